"""Stage "opendrive": read netconvert's OpenDRIVE with our exact reader, check its georeference, and record
what it holds (report/opendrive.json). A file our reader cannot read fails the build here, not in the mesher.

netconvert's output is never trusted: a vertex it could not compute (SUMO's invalid-position sentinel), one
off Earth or far outside the network's extent, and absurd lengths are repaired (tavf_mapkit/opendrive/repair.py),
then what keeps the file from being read alike by every reader (``_repair_steps``: @length that is not the
curve's arc length, ...), and NAME.xodr is rewritten; each repair is counted in the facts (``repairs``) and named
in the build's output. A file broken beyond repair fails here with one line naming road and line.
``--no-repair`` ([opendrive] repair = false) keeps netconvert's file as it is for comparison, except for the
first step: geometry that cannot be built on at all (a road to the sentinel, 3,000,000 km long) is still repaired.

When the build's input is an OpenDRIVE file (no extract, no netconvert), this stage brings it into the build
as NAME.xodr (tavf_mapkit/opendrive/importing.py) and decides the driving side from its roads' ``rule``
(or [pipeline] driving_side / --driving-side). Its defects are the user's to fix: an implausible number
refuses the build with one line naming the file's road and line (the sampling budget, when it is summarised)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("opendrive")
class OpenDriveStage(Stage):
    makes = ("xodr", "odrmap", "opendrive_report", "xodr_counts")
    inputs = ("xodr",)
    # 2: an OpenDRIVE input becomes the build's NAME.xodr; 3: netconvert's output repaired; 4: @length set to the
    # arc length, [opendrive] repair; 5: connecting roads meet their lanes, one <controller> per id; 6: curves as
    # arcs ([opendrive] curves); 7: NAME.xodr is always this stage's (netconvert's file stays in netconvert/);
    # 8: NAME.odrmap, the snapshot of NAME.xodr as read (opendrive/snapshot.py) for the stages and twins after it;
    # 9: a paramPoly3's arc length exact across a near-cusp (its @length repaired right, its arcs fitted);
    # 10: NAME.odrmap keyed by the file's sha256 taken as it is written (and the snapshot code's new key),
    # report/xodr_counts.json (what the report counts in NAME.xodr, counted as it is written)
    version = "10"
    description = "read and check the OpenDRIVE (counts, bounds, georeference plausibility)"

    def options(self, context: BuildContext) -> dict:
        if context.input_kind == "opendrive":
            return {"driving_side": context.config.driving_side}
        if not repair_enabled(context):
            return {"repair": False}
        return {"repair": True, "curves": curves_mode(context)}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.opendrive.summary import summarise

        files, more_facts, written = {}, {}, None
        if context.input_kind == "opendrive":
            odr, more_facts = _import_input(context)
            files["xodr"] = f"{context.name}.xodr"
        else:
            odr, repaired_facts, written = _repaired_netconvert_output(context)
            files["xodr"] = f"{context.name}.xodr"
            more_facts["repairs"] = repaired_facts
            if not repair_enabled(context):
                more_facts["repair"] = False  # --no-repair: "no repairs" does not mean none were needed
        summary = summarise(odr)
        del odr  # not held while NAME.xodr is read back for its snapshot
        summary["file"] = files["xodr"]
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
            **more_facts,
        }
        if written is not None and written.counts is not None:
            files["xodr_counts"] = _write_counts(context, files["xodr"], written)
        files["odrmap"] = _snapshot(context, files["xodr"], written.sha256 if written is not None else None)
        return StageOutput(files={**files, "opendrive_report": "report/opendrive.json"}, facts=facts)


#: what the report counts in NAME.xodr (pipeline/summary.py), as the writer counted it
COUNTS_FILE = "report/xodr_counts.json"


def _write_counts(context: BuildContext, xodr_name: str, written) -> str:
    """report/xodr_counts.json: the counts of the report's "opendrive" part, taken as NAME.xodr was written, with
    the file's size and sha256 -- the report stage need not parse a region's 500 MB again for them."""
    xodr = context.output_path(xodr_name)
    record = {"file": xodr_name, "bytes": xodr.stat().st_size, "sha256": written.sha256, "counts": written.counts}
    context.output_path(COUNTS_FILE).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return COUNTS_FILE


def _snapshot(context: BuildContext, xodr_name: str, sha256: str | None = None) -> str:
    """Read NAME.xodr back as every later reader would and save that as NAME.odrmap: the stages after this one
    and the twin load a region's map from it in a tenth of the time (opendrive/snapshot.py). The map read is kept
    for the mesh stage when it is small (stage_map.py). ``sha256``: the file's, when it was taken as it was
    written (else the file is hashed)."""
    from tavf_mapkit.memory import return_freed_memory
    from tavf_mapkit.opendrive.snapshot import SUFFIX, snapshot_file
    from tavf_mapkit.pipeline.builtin.stage_map import keep_map

    return_freed_memory()
    xodr = context.output_path(xodr_name)
    name = f"{context.name}{SUFFIX}"
    keep_map(context, xodr, snapshot_file(xodr, context.output_path(name), sha256=sha256))
    return name


#: netconvert's output with more dropped roads than this share (and at least MAX_DROPPED_MIN) is not repaired
MAX_DROPPED_SHARE = 0.05
MAX_DROPPED_MIN = 10


def repair_enabled(context: BuildContext) -> bool:
    """[opendrive] repair (``mapkit build --no-repair`` sets it false); true unless said otherwise."""
    return bool(context.section("opendrive").get("repair", True))


def curves_mode(context: BuildContext) -> str:
    """[opendrive] curves: "arcs" (paramPoly3 and poly3 become arcs and lines, the default) or "keep"."""
    return str(context.section("opendrive").get("curves", "arcs"))


def _repair_steps(context: BuildContext) -> list:
    """The repairs of netconvert's OpenDRIVE in the order they run: each takes the map the one before returned
    and returns (map, [Repair]). The first makes a build possible at all and runs even with --no-repair; the
    others make the file one that every reader reads alike. A new repair is one more entry, in its own module."""
    from tavf_mapkit.opendrive.repair import repair_untrusted_geometry
    from tavf_mapkit.opendrive.repair_contacts import repair_contacts
    from tavf_mapkit.opendrive.repair_controllers import repair_controllers
    from tavf_mapkit.opendrive.repair_curves import repair_curves
    from tavf_mapkit.opendrive.repair_lengths import repair_geometry_lengths
    from tavf_mapkit.opendrive.repair_redundant import repair_redundant

    extent = _network_extent(context)
    steps = [lambda odr: repair_untrusted_geometry(odr, extent)]
    if repair_enabled(context):
        steps += [
            repair_geometry_lengths,  # @length = arc length; everything along s moved with it
            repair_redundant,  # consecutive lines that are one line, records that repeat the one before
            repair_contacts,  # connecting roads meet the lanes they link (or their link goes)
            repair_controllers,  # one <controller> per id
        ]
        if curves_mode(context) == "arcs":
            # last, so that the connecting roads rebuilt above are among them
            # paramPoly3 and poly3 as arcs and lines every reader evaluates exactly
            steps.append(lambda odr: repair_curves(odr, progress=context.progress))
    return steps


def _repaired_netconvert_output(context: BuildContext):
    """(netconvert's OpenDRIVE with its impossible geometry repaired, written as NAME.xodr -- netconvert's file byte
    for byte when nothing was; the repairs' facts, ``repair_facts``; what the writer knows of the file it wrote,
    ``writer.WrittenOpenDrive``, or None when the file is netconvert's)."""
    from tavf_mapkit.errors import StageError
    from tavf_mapkit.memory import return_freed_memory
    from tavf_mapkit.opendrive.repair import DROPPED_ROAD
    from tavf_mapkit.opendrive.writer import write_opendrive

    repaired, repairs = context.opendrive(), []
    roads = len(repaired.roads)
    # netconvert's map is not held while the repairs run: each step's map goes when the next one's is made, so
    # the roads a repair replaced, and the map-wide tables the repairs built of them, are not held beside the
    # repaired map's (Columbus: 5 million arcs and lines where netconvert wrote 0.5 million curves)
    for step in _repair_steps(context):
        repaired, made = step(repaired)
        repairs += made
    raw = context.artifacts["xodr"]  # netconvert's (netconvert/NAME.xodr), which stays as it is
    xodr = context.output_path(f"{context.name}.xodr")
    if not repairs:  # every step returned the map it was given
        if raw.resolve() != xodr.resolve():
            shutil.copyfile(raw, xodr)
        return repaired, {}, None
    return_freed_memory()
    dropped = [repair for repair in repairs if repair.action == DROPPED_ROAD]
    if len(dropped) > max(MAX_DROPPED_MIN, MAX_DROPPED_SHARE * roads):
        first = dropped[0]
        raise StageError(f"netconvert's OpenDRIVE is broken beyond repair ({len(dropped)} of {roads} "
                         f"roads would be dropped); the first: {first.detail}",
                         file=str(raw.relative_to(context.folder)), line=first.line, road=first.road)
    by_action: dict = {}
    for repair in repairs:
        by_action.setdefault(repair.action, []).append(repair)
    for action, made in by_action.items():  # one line per kind of repair: hundreds are routine
        more = f" (and {len(made) - 1} more of {action!r}: facts of stage opendrive in manifest.json)" \
            if len(made) > 1 else ""
        context.note(f"repaired netconvert's OpenDRIVE: {made[0]}{more}")
    # what the manifest keeps of the repairs; the records go before the map is written and summarised (a city's
    # 300,000 with their texts: 70 MB)
    facts = repair_facts(repairs)
    del repairs, by_action, dropped, made
    # netconvert stamps its output with the time (header @date): without the stamp the repaired file depends on
    # the input only, so the stages after this one are reused when netconvert had to run again
    repaired = repaired.with_header(replace(repaired.header, date=None))
    written = write_opendrive(repaired, xodr)
    return repaired, facts, written


def _network_extent(context: BuildContext):
    """The extent of the SUMO network netconvert wrote beside the OpenDRIVE (its <location convBoundary>, in the
    same local coordinates), when there is one and it is itself a place on Earth."""
    from tavf_mapkit.errors import InputError
    from tavf_mapkit.opendrive.plausibility import Extent, off_earth
    from tavf_mapkit.sumonet import read_location

    net = context.artifacts.get("net")
    if net is None:
        return None
    try:
        west, south, east, north = read_location(net).conv_boundary
    except InputError:
        return None
    if off_earth([west, east], [south, north]).any() or not (west <= east and south <= north):
        return None
    return Extent(west, south, east, north)


def repair_facts(repairs) -> dict:
    """{action: {count, roads}} for the manifest: how often each repair was made, and on which roads (first 20)."""
    facts: dict = {}
    for repair in repairs:
        entry = facts.setdefault(repair.action, {"count": 0, "roads": []})
        entry["count"] += 1
        if len(entry["roads"]) < 20:
            entry["roads"].append(repair.road)
    return facts


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
