"""Stage "netconvert": source -> NAME.net.xml + netconvert/NAME.xodr with a profile (see tavf_mapkit.netconvert).

The opendrive stage reads netconvert's OpenDRIVE and writes the build's NAME.xodr from it."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.pipeline.config import DEFAULT_CRS, DEFAULT_PROFILE
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


#: where netconvert's own OpenDRIVE goes in the build folder (the build's NAME.xodr is the opendrive stage's)
RAW_XODR = "netconvert/{name}.xodr"


@register_stage("netconvert")
class NetconvertStage(Stage):
    makes = ("net", "xodr", "netconvert_log")
    inputs = ("source",)
    input_kinds = ("osm", "sumo-net")
    # 2: local (0, 0) at the projection origin (no <offset>); 3: driving side (--lefthand); 4: the projection
    # centred on the road network when the extract's centre lies far from it
    # 5: its OpenDRIVE is netconvert/NAME.xodr (the opendrive stage writes NAME.xodr)
    version = "5"
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
            "driving_side": driving_side(context).side,
        }
        if context.input_kind == "sumo-net" and "bbox" in context.section("area"):
            options["clip_bbox"] = context.section("area")["bbox"]
        return options

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.netconvert import convert, load_profile
        from tavf_mapkit.projection import describe_georeference, read_xodr_georeference

        settings = context.section("netconvert")
        profile = load_profile(settings.get("profile", DEFAULT_PROFILE))
        # netconvert's OpenDRIVE gets a place of its own: the opendrive stage writes the repaired NAME.xodr, and a
        # file that a later stage replaced would make every rebuild run netconvert and the repairs again
        net, xodr, log = f"{context.name}.net.xml", RAW_XODR.format(name=context.name), "logs/netconvert.log"
        context.output_path(xodr)
        centre = context.facts.get("extract", {}).get("centre")
        clip = context.section("area").get("bbox") if context.input_kind == "sumo-net" else None
        side = driving_side(context)
        # OSM: netconvert's default is right-hand; a SUMO network: always say it, a re-projection through plain
        # XML would lose the network's own lefthand flag
        lefthand = side.lefthand if side.lefthand or context.input_kind == "sumo-net" else None
        _note_disagreement(context, side)
        source = context.artifacts["source"].relative_to(context.folder)
        conversion = convert(source, context.input_kind, Path(net), Path(xodr), Path(log), profile,
                             crs=settings.get("crs", DEFAULT_CRS), centre=tuple(centre) if centre else None,
                             clip_bbox=tuple(clip) if clip else None, cwd=context.folder, lefthand=lefthand)
        facts = conversion.to_dict()
        facts.pop("seconds", None)  # timings live in the manifest's stage record, facts stay deterministic
        facts["profile"] = profile.name
        facts["georeference"] = describe_georeference(read_xodr_georeference(context.folder / xodr))
        facts["driving_side"] = side.to_dict()
        return StageOutput(files={"net": net, "xodr": xodr, "netconvert_log": log}, facts=facts)


def driving_side(context: BuildContext):
    """The side to build for: [pipeline] driving_side / --driving-side when left or right; else (auto) a SUMO
    network's own lefthand flag, or for OSM the country under the extract's centre."""
    from tavf_mapkit.drivingside import DrivingSide, choose

    extract = context.facts.get("extract", {})
    if context.input_kind == "sumo-net":
        lefthand = bool(extract.get("lefthand"))
        detected = DrivingSide("left" if lefthand else "right", "sumo-net",
                               'the SUMO network says lefthand="true"' if lefthand else
                               'the SUMO network has no lefthand="true"')
    else:
        located = extract.get("location_driving_side")
        detected = DrivingSide.from_dict(located) if located else None
    return choose(context.config.driving_side, detected)


def _note_disagreement(context: BuildContext, side) -> None:
    """Tell the user when the side built differs from the country's (a SUMO network made for the other side,
    or an override): not an error, but worth a line."""
    located = context.facts.get("extract", {}).get("location_driving_side")
    if located and located["side"] != side.side:
        context.note(f"driving side: {side.reason}, although {located['why']}")
