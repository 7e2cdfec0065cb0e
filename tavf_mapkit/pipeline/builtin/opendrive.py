"""Stage "opendrive": read netconvert's OpenDRIVE with our exact reader, check its georeference, and record
what it holds (report/opendrive.json). A file our reader cannot read fails the build here, not in the mesher.

When the build's input is an OpenDRIVE file (no extract, no netconvert), this stage brings it into the build
as NAME.xodr (tavf_mapkit/opendrive/importing.py) and decides the driving side from its roads' ``rule``
(or [pipeline] driving_side / --driving-side)."""

from __future__ import annotations

import json

from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("opendrive")
class OpenDriveStage(Stage):
    inputs = ("xodr",)
    version = "2"  # 2: an OpenDRIVE input becomes the build's NAME.xodr
    description = "read and check the OpenDRIVE (counts, bounds, georeference plausibility)"

    def options(self, context: BuildContext) -> dict:
        return {"driving_side": context.config.driving_side} if context.input_kind == "opendrive" else {}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.opendrive.summary import summarise

        files, imported = {}, {}
        if context.input_kind == "opendrive":
            odr, imported = _import_input(context)
            files["xodr"] = f"{context.name}.xodr"
        else:
            odr = context.opendrive()
        summary = summarise(odr)
        summary["file"] = files.get("xodr") or context.artifacts["xodr"].name
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
            **imported,
        }
        return StageOutput(files={**files, "opendrive_report": "report/opendrive.json"}, facts=facts)


def _import_input(context: BuildContext):
    """Read the user's OpenDRIVE file (unreadable: a one-line InputError naming it, exit 2), write the build's
    copy, and return the map with the facts only an input file has (driving side, georeference)."""
    from tavf_mapkit.errors import InputError
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.opendrive.importing import RULES, map_driving_side, write_build_copy
    from tavf_mapkit.projection import describe_georeference

    odr = load_opendrive(context.input_path)
    if not odr.roads:
        raise InputError("the OpenDRIVE file has no <road>", file=str(context.input_path))
    side, rewrite = map_driving_side(odr, context.config.driving_side)
    copy = context.output_path(f"{context.name}.xodr")
    write_build_copy(context.input_path, copy, RULES[side.side] if rewrite else None)
    if rewrite:
        odr = load_opendrive(copy)  # the copy, with the rules it drives by
    offset = odr.header.offset
    georeference = None
    if odr.header.geo_reference:
        georeference = describe_georeference({
            "proj": " ".join(odr.header.geo_reference.split()),
            "offset": {key: getattr(offset, key) for key in ("x", "y", "z", "hdg")} if offset else None})
    _note_location(context, odr, side)
    return odr, {"driving_side": side.to_dict(), "georeference": georeference}


def _note_location(context: BuildContext, odr, side) -> None:
    """A map whose roads drive on the other side than the country it is placed in gets a line (not an error:
    the file's own rules decide; --driving-side overrides them)."""
    from tavf_mapkit.drivingside import side_at
    from tavf_mapkit.errors import InputError

    if odr.georeference is None:
        return
    try:
        west, south, east, north = odr.bounds(step=10.0)
        lon, lat = odr.georeference.local_to_wgs84(0.5 * (west + east), 0.5 * (south + north))
        located = side_at(float(lon), float(lat))
    except InputError:
        return
    if located.country is not None and located.side != side.side:
        context.note(f"driving side: {side.reason}, although {located.why}")
