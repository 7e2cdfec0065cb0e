"""Stage "opendrive": read netconvert's OpenDRIVE with our exact reader, check its georeference, and record
what it holds (report/opendrive.json). A file our reader cannot read fails the build here, not in the mesher."""

from __future__ import annotations

import json

from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("opendrive")
class OpenDriveStage(Stage):
    inputs = ("xodr",)
    version = "1"
    description = "read and check the OpenDRIVE (counts, bounds, georeference plausibility)"

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.opendrive.summary import summarise

        odr = context.opendrive()
        summary = summarise(odr)
        summary["file"] = context.artifacts["xodr"].name
        path = context.output_path("report/opendrive.json")
        path.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
        geo = summary["georeference"] or {}
        if geo and not geo.get("plausible", False):
            context.note("georeference NOT plausible: " + "; ".join(geo.get("problems", [])))
        counts = summary["counts"]
        facts = {
            "roads": counts["roads"], "junctions": counts["junctions"], "lanes": counts["lanes"],
            "length_km": round(summary["total_length_m"] / 1000.0, 3), "signals": counts["signals"],
            "reader_warnings": len(summary["warnings"]),
            "georeference_plausible": bool(geo.get("plausible", False)),
            "carla_readable": bool(geo.get("carla_readable", False)),
            "bounds_wgs84": {k: round(v, 7) for k, v in (geo.get("bounds_wgs84") or {}).items()},
        }
        return StageOutput(files={"opendrive_report": "report/opendrive.json"}, facts=facts)
