"""The build report (report/summary.json) and the one-screen summary printed at the end of a build."""

from __future__ import annotations

import json
from pathlib import Path

from tavf_mapkit.pipeline.manifest import OSM_ATTRIBUTION


def opendrive_counts(xodr: Path) -> dict:
    """Roads, junctions, signals, objects and total road length of an OpenDRIVE file (one streaming pass;
    ``opendrive.summary.ElementCounts`` says what is counted)."""
    from tavf_mapkit.opendrive.summary import COUNTED_TAGS, ElementCounts
    from tavf_mapkit.xmlsafe import iterparse_safe, read_xml_source, release_if_top_level

    counts = ElementCounts()
    for _event, element in iterparse_safe(read_xml_source(xodr), events=("end",), tag=COUNTED_TAGS):
        counts.ended(element)
        release_if_top_level(element)  # a road or junction done: it goes (a region's file is GBs)
    return counts.as_dict()


def written_counts(context) -> dict | None:
    """``opendrive_counts`` of the build's NAME.xodr as its writer counted them (artifact ``xodr_counts``, made with
    it by the opendrive stage), when they are of that file; else None."""
    path = context.artifacts.get("xodr_counts")
    if path is None:
        return None
    xodr = context.artifacts["xodr"]
    try:
        record = json.loads(Path(path).read_text(encoding="utf-8"))
        if record["file"] == xodr.name and record["bytes"] == xodr.stat().st_size:
            return dict(record["counts"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def build_report(context) -> dict:
    """Everything the report shows, from the artifacts and the facts of the stages before it."""
    extract = context.facts.get("extract", {})
    netconvert = context.facts.get("netconvert", {})
    report = {
        "name": context.name,
        "input": {"file": context.input_path.name, "kind": context.input_kind},
        "attribution": OSM_ATTRIBUTION if derived_from_osm(context.input_path, context.input_kind) else None,
    }
    if context.input_kind == "osm" and extract:
        report["osm"] = {key: extract.get(key) for key in (
            "nodes", "ways", "relations", "highway_ways", "traffic_signals", "traffic_signs", "buildings",
            "turn_restrictions", "bbox", "centre", "area")}
    elif extract:
        report["sumo_input"] = {key: extract.get(key) for key in (
            "edges", "lanes", "junctions", "traffic_lights", "location")}
    if netconvert:
        report["netconvert"] = {key: netconvert.get(key) for key in (
            "netconvert", "profile", "projection", "warnings", "warning_kinds", "warnings_by_kind", "notes")}
        report["georeference"] = netconvert.get("georeference")
    for name, facts in context.facts.items():
        if name not in ("extract", "netconvert", "report") and isinstance(facts, dict):
            report.setdefault("stages", {})[name] = facts
            if facts.get("georeference"):
                report["georeference"] = facts["georeference"]
    for facts in context.facts.values():
        if isinstance(facts, dict) and facts.get("driving_side"):
            report["driving_side"] = facts["driving_side"]
    if "xodr" in context.artifacts:
        xodr = context.artifacts["xodr"]
        report["opendrive"] = {"file": xodr.name, **(written_counts(context) or opendrive_counts(xodr))}
    tiles = tile_report(context.folder)
    if tiles:
        report["tiles"] = tiles
    if "net" in context.artifacts:
        from tavf_mapkit.sumonet import check_sumo_net

        net = check_sumo_net(context.artifacts["net"])
        report["sumo_net"] = {"file": context.artifacts["net"].name,
                              **{key: net[key] for key in ("edges", "lanes", "junctions", "traffic_lights")}}
    return report


def tile_report(folder: Path) -> dict | None:
    """The build's tile grid (``tavf_mapkit.tilegrid``) as the mesh files and the collision world record it:
    size, origin, how many tiles each has and the range of their indices; None without either."""
    from tavf_mapkit.tilegrid import TileGrid, tile_name

    grids, out = {}, {}
    for part, path, key in (("mesh", "mesh/mesh.json", "tiles"), ("collision", "collision/world.json", "tiles")):
        try:
            document = json.loads((Path(folder) / path).read_text(encoding="utf-8"))
            grids[part] = TileGrid.of(document)
            indices = [tuple(entry["index"]) for entry in document[key]]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        out[part] = {"tiles": len(indices)}
        if indices:
            low, high = (min(i for i, _ in indices), min(j for _, j in indices)), \
                (max(i for i, _ in indices), max(j for _, j in indices))
            out[part]["south_west"], out[part]["north_east"] = tile_name(low), tile_name(high)
    if not grids:
        return None
    grid = grids.get("mesh") or grids["collision"]
    return {"size": grid.size, "origin": list(grid.origin), **out,
            # [mesh] tile and [collision] tile may be set apart; then the names stand for other squares
            "one_grid": len(set(grids.values())) == 1}


def report_text(report: dict) -> str:
    """The content part of the summary: what the build holds (no timings, no stage statuses)."""
    lines = []
    osm = report.get("osm")
    if osm:
        highway = sum((osm.get("highway_ways") or {}).values())
        lines.append(f"input   {report['input']['file']}: {osm['nodes']} nodes, {osm['ways']} ways "
                     f"({highway} highway), {osm['buildings']} buildings, "
                     f"{osm['traffic_signals']} signal nodes, {osm['traffic_signs']} signs, "
                     f"{osm['turn_restrictions']} turn restrictions")
        if osm.get("area"):
            lines.append(f"area    {osm['area']['description']}")
    sumo_input = report.get("sumo_input")
    if sumo_input:
        lines.append(f"input   {report['input']['file']}: SUMO network, {sumo_input['edges']} edges, "
                     f"{sumo_input['junctions']} junctions, {sumo_input['traffic_lights']} traffic lights")
    opendrive = report.get("opendrive")
    if opendrive:
        lines.append(f"xodr    {opendrive['file']}: {opendrive['roads']} roads "
                     f"({opendrive['road_length_km']:.1f} km), {opendrive['junctions']} junctions, "
                     f"{opendrive['signals']} signals, {opendrive['objects']} objects")
    tiles = report.get("tiles")
    if tiles:
        counts = " + ".join(f"{tiles[part]['tiles']} {part}" for part in ("mesh", "collision") if part in tiles)
        origin = tiles["origin"]
        lines.append(f"tiles   {counts} tiles of {tiles['size']:g} m centred on local ({origin[0]:g}, {origin[1]:g})"
                     + ("" if tiles["one_grid"] else "; mesh and collision on different grids ([mesh] tile "
                                                    "differs from [collision] tile)"))
    net = report.get("sumo_net")
    if net:
        lines.append(f"net     {net['file']}: {net['edges']} edges, {net['lanes']} lanes, "
                     f"{net['junctions']} junctions, {net['traffic_lights']} traffic lights")
    netconvert = report.get("netconvert")
    if netconvert:
        lines.append(f"netconvert  {netconvert['netconvert']}, profile {netconvert['profile']}: "
                     f"{netconvert['warnings']} warnings of {netconvert['warning_kinds']} kinds "
                     "(logs/netconvert.log)")
        for kind, count in list((netconvert.get("warnings_by_kind") or {}).items())[:3]:
            lines.append(f"    {count:4d} x {_shorten(kind, 88)}")
        for note in netconvert.get("notes") or []:
            lines.append(f"    note: {_shorten(note, 100)}")
    stages = report.get("stages") or {}
    repairs = (stages.get("opendrive") or {}).get("repairs")
    if repairs is not None:
        from tavf_mapkit.pipeline.builtin.check import repair_rows

        rows = repair_rows(repairs)
        lines.append("repairs " + (", ".join(f"{row['repair']} {row['count']}" if row["count"] is not None
                                             else row["repair"] for row in rows) or "none needed"))
    check = stages.get("check")
    if check and check.get("status"):
        lines.append(check_line(check))
    side = report.get("driving_side")
    if side:
        lines.append(f"side    {side['reason']}")
    georeference = report.get("georeference")
    if georeference:
        offset = georeference.get("offset") or {}
        lines.append(f"geo     {georeference.get('proj')}")
        if offset:
            lines.append(f"        offset x={offset.get('x')} y={offset.get('y')} "
                         "(projected = local + offset)")
    if report.get("attribution"):
        lines.append(f"data    {report['attribution']}")
    return "\n".join(lines)


def check_line(check: dict) -> str:
    """The check stage's verdict in one line: what failed against which limit, and the page to read."""
    status = check["status"]
    by_rule = check.get("validate_errors_by_rule") or {}
    errors = ", ".join(f"{rule} {n}" for rule, n in sorted(by_rule.items(), key=lambda item: -item[1])[:3])
    more = f" (+{len(by_rule) - 3} rules)" if len(by_rule) > 3 else ""
    line = (f"check   {status.upper()}: {check.get('validate_errors')} validation errors"
            + (f" ({errors}{more})" if errors else "") + f", {check.get('validate_warnings')} warnings")
    failed = check.get("failed_checks") or []
    if failed:
        line += "; over the limit: " + "; ".join(
            f"{c['what']} {c['value']} {'>' if c.get('kind') == 'max' else '<'} {c['limit']}" for c in failed)
    return line + " (report/index.html)"


def render_summary(manifest: dict, folder: Path) -> str:
    """The one-screen summary: where, how long, each stage's status, then the report's content."""
    stages = manifest.get("stages", [])
    lines = [f"built {folder} in {manifest.get('seconds', 0):.2f} s"]
    for record in stages:
        status = record["status"]
        seconds = f" {record['seconds']:.2f} s" if status == "ran" else ""
        note = f" ({record['note']})" if record.get("note") else ""
        lines.append(f"  {record['name']:<11} {status}{seconds}{note}")
    report_path = folder / "report" / "summary.json"
    if report_path.is_file():
        try:
            lines.append(report_text(json.loads(report_path.read_text(encoding="utf-8"))))
        except ValueError:
            pass
    return "\n".join(lines)


def derived_from_osm(input_path: Path, kind: str) -> bool:
    """OSM input, or a SUMO network imported from OSM (OSM edge types, an OSM file in its configuration)."""
    if kind == "osm":
        return True
    from tavf_mapkit.sumonet import read_net_bytes

    head = read_net_bytes(input_path)[: 1 << 22]
    return b'type="highway.' in head or b"osm-files" in head or b"openstreetmap" in head.lower()


def _shorten(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"
