"""Stage "extract": the build's own copy of its input, made safe for netconvert.

OSM input is re-written by osmium (clipped to the pipeline's area if it has one) into source/NAME.osm;
a SUMO network is checked (well-formed, <net> root, no DOCTYPE) and copied to source/NAME.net.xml[.gz].
Both record the driving side of the country under the input's centre (``location_driving_side``), which the
netconvert stage uses unless told otherwise; looked up here, once per input, not on every rebuild.
"""

from __future__ import annotations

import shutil

from tavf_mapkit.errors import InputError
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("extract")
class ExtractStage(Stage):
    makes = ("source",)
    inputs = ("input",)
    input_kinds = ("osm", "sumo-net")
    version = "2"  # 2: location_driving_side (and a SUMO network's lefthand flag)
    description = "sanitise (and clip) the input with osmium; copy a SUMO network"

    def options(self, context: BuildContext) -> dict:
        area = context.section("area")
        if context.input_kind == "osm":
            return {"area": area, "routes": context.section("extract").get("routes", False)}
        return {}

    def run(self, context: BuildContext) -> StageOutput:
        if context.input_kind == "osm":
            return self._osm(context)
        return self._sumo_net(context)

    def _osm(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.osm.area import bbox_area, load_polygon
        from tavf_mapkit.osm.extract import extract

        area_options = context.section("area")
        area = None
        if "polygon_path" in area_options:
            area = load_polygon(area_options["polygon_path"])
        elif "bbox" in area_options:
            area = bbox_area(area_options["bbox"])
        relative = f"source/{context.name}.osm"
        summary = extract(context.input_path, context.output_path(relative), area,
                          routes=bool(context.section("extract").get("routes", False)))
        facts = summary.to_dict()
        facts["output"] = relative
        facts["kind"] = "osm"
        facts["location_driving_side"] = _location_side(facts.get("centre"))
        return StageOutput(files={"source": relative}, facts=facts)

    def _sumo_net(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.sumonet import check_sumo_net

        if "polygon_path" in context.section("area"):
            raise InputError("--polygon applies to OSM input; a SUMO network can be clipped with --bbox only",
                             file=str(context.input_path))
        facts = check_sumo_net(context.input_path)
        suffix = ".net.xml.gz" if str(context.input_path).lower().endswith(".gz") else ".net.xml"
        relative = f"source/{context.name}{suffix}"
        shutil.copyfile(context.input_path, context.output_path(relative))
        facts["kind"] = "sumo-net"
        facts["output"] = relative
        facts["location_driving_side"] = _location_side(facts.get("centre_wgs84"))
        return StageOutput(files={"source": relative}, facts=facts)


def _location_side(centre) -> dict | None:
    """The driving side at the (lon, lat) centre of the input, None without a centre."""
    from tavf_mapkit.drivingside import side_at

    return side_at(*centre).to_dict() if centre else None
