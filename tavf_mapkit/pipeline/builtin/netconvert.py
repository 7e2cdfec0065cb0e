"""Stage "netconvert": source -> NAME.net.xml + NAME.xodr with a profile (see tavf_mapkit.netconvert)."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.pipeline.config import DEFAULT_CRS, DEFAULT_PROFILE
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("netconvert")
class NetconvertStage(Stage):
    inputs = ("source",)
    version = "2"  # 2: local (0, 0) at the projection origin (no <offset>)
    description = "SUMO netconvert: road network and OpenDRIVE"

    def options(self, context: BuildContext) -> dict:
        from tavf_mapkit.netconvert import load_profile, netconvert_version

        settings = context.section("netconvert")
        profile = load_profile(settings.get("profile", DEFAULT_PROFILE))
        options = {
            "netconvert": netconvert_version(),
            "profile": profile.name,
            "profile_options": profile.options_for(context.input_kind),
            "crs": settings.get("crs", DEFAULT_CRS),
        }
        if context.input_kind == "sumo-net" and "bbox" in context.section("area"):
            options["clip_bbox"] = context.section("area")["bbox"]
        return options

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.netconvert import convert, load_profile
        from tavf_mapkit.projection import describe_georeference, read_xodr_georeference

        settings = context.section("netconvert")
        profile = load_profile(settings.get("profile", DEFAULT_PROFILE))
        net, xodr, log = f"{context.name}.net.xml", f"{context.name}.xodr", "logs/netconvert.log"
        centre = context.facts.get("extract", {}).get("centre")
        clip = context.section("area").get("bbox") if context.input_kind == "sumo-net" else None
        source = context.artifacts["source"].relative_to(context.folder)
        conversion = convert(source, context.input_kind, Path(net), Path(xodr), Path(log), profile,
                             crs=settings.get("crs", DEFAULT_CRS), centre=tuple(centre) if centre else None,
                             clip_bbox=tuple(clip) if clip else None, cwd=context.folder)
        facts = conversion.to_dict()
        facts.pop("seconds", None)  # timings live in the manifest's stage record, facts stay deterministic
        facts["profile"] = profile.name
        facts["georeference"] = describe_georeference(read_xodr_georeference(context.folder / xodr))
        return StageOutput(files={"net": net, "xodr": xodr, "netconvert_log": log}, facts=facts)
