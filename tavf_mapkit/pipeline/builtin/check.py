"""Stage "check": validate the OpenDRIVE, check the georeference round trip, and measure the build against
the references the pipeline file names ([check] reference_network_path, gnss_trace_path) with the
thresholds of [check.thresholds]. Writes report/check.json, report/validate.json, report/compare.json,
report/match-trace.json, PNG plots and report/index.html (one self-contained page, with the 2D map of
``mapkit view`` embedded: lanes, findings, repairs, the GNSS trace; it opens from disk with no server).

The verdict counts validation findings too ([check.validation]): by default every validation error of the
build's OpenDRIVE fails the check (``max_errors = 0``); ``max_warnings`` limits warnings, and
``[check.validation.rules]`` gives single rules their own limit (their findings then count only there). The
page lists the findings per rule and the repairs the opendrive stage recorded in its facts (``repairs``).

A threshold that is not met is reported (facts, check.json, the page, the build's summary), not fatal: the
build is still usable and exits 0 (docs/build-folder.md); CI guards accuracy through the baselines of
tests/test_accuracy_regression.py.
"""

from __future__ import annotations

import json

import numpy as np

from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.memory import frozen_heap
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage

# threshold key -> (where the value comes from, comparison)
THRESHOLDS = {
    "reference_median_offset_m": ("compare", "offset median (m)", lambda r: r["offset"]["median_m"], "max"),
    "reference_p95_offset_m": ("compare", "offset p95 (m)", lambda r: r["offset"]["p95_m"], "max"),
    "reference_min_coverage": ("compare", "reference length covered within 3 m", lambda r: r["recall"]["3"], "min"),
    "gnss_median_distance_m": ("match", "GNSS fix distance median (m)", lambda r: r["median_m"], "max"),
    "gnss_p95_distance_m": ("match", "GNSS fix distance p95 (m)", lambda r: r["p95_m"], "max"),
    "georeference_roundtrip_m": ("georeference", "local -> WGS84 -> local (m)", lambda r: r["roundtrip_m"], "max"),
}


@register_stage("check")
class CheckStage(Stage):
    makes = ("check_report", "check_html", "validate_report", "compare_report", "compare_plot", "match_report",
             "match_plot")
    # reads only NAME.xodr and the opendrive stage's facts: on a second core it validates while the tile stages run
    runs_beside = True
    inputs = ("xodr",)
    # 2: compare.json names the xodr by file name; 3: validation findings in the verdict; 4: the page's map
    version = "5"
    description = "validate, georeference round trip, compare / match-trace against the pipeline's references"

    def options(self, context: BuildContext) -> dict:
        # the opendrive stage's repairs are shown on the page, so they decide whether it is up to date
        return {"check": context.section("check"), "repairs": _repairs(context)}

    def run(self, context: BuildContext) -> StageOutput:
        section = context.section("check")
        thresholds = section.get("thresholds", {}) or {}
        xodr = context.artifacts["xodr"]
        files: dict[str, str] = {}
        results: dict = {"file": xodr.name}
        # validation reads the file once for both its document rules and its map rules, never holding both
        # (each is about a gigabyte for a large map); the map it loaded serves the checks below
        results["validate"], odr, findings = self._validate(context, xodr, files)
        # the map lives to the end: its millions of objects are kept out of the collector's scans meanwhile, or
        # the page's allocations would walk them again and again (seconds each)
        with frozen_heap():
            return self._check_and_page(context, section, thresholds, xodr, files, results, odr, findings)

    def _check_and_page(self, context, section, thresholds, xodr, files, results, odr, findings) -> StageOutput:
        """The checks after validation, check.json and the page (``run`` after the map is loaded)."""
        results["georeference"] = _roundtrip(odr)
        reference = section.get("reference_network_path")
        if reference is not None:
            results["compare"] = self._compare(context, xodr, reference, files)
        trace = section.get("gnss_trace_path")
        matched = None
        if trace is not None:
            results["match"], matched = self._match(context, odr, trace, files)
        checks = _validation_checks(results["validate"], section.get("validation") or {})
        checks += _evaluate(results, thresholds)
        results["checks"] = checks
        results["repairs"] = _repairs(context)
        failed = [c for c in checks if c["passed"] is False]
        unchecked = any(c["passed"] is None for c in checks if c["key"].startswith("validation."))
        # never "pass" for a file whose validation did not run: that would claim what nobody checked
        results["status"] = "fail" if failed else "unchecked" if unchecked else "pass"
        for check in failed:
            context.note(f"check failed: {check['what']} = {check['value']} (threshold {check['limit']})")
        path = context.output_path("report/check.json")
        path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
        files["check_report"] = "report/check.json"
        # the page is written in its parts: for a city its map is tens of megabytes of text, not to be copied
        with context.output_path("report/index.html").open("w", encoding="utf-8") as html:
            html.writelines(_html_parts(results, context, _page_map(context, odr, findings, matched)))
        files["check_html"] = "report/index.html"
        validate = results["validate"] or {}
        facts = {
            "status": results["status"], "failed": [c["key"] for c in failed],
            "validate_errors": validate.get("errors"), "validate_warnings": validate.get("warnings"),
            "validate_errors_by_rule": validate.get("errors_by_rule"),
            "failed_checks": [{key: c.get(key) for key in ("key", "what", "value", "limit", "kind")}
                              for c in failed],
            "georeference_roundtrip_m": results["georeference"]["roundtrip_m"],
        }
        compare = results.get("compare") or {}
        if compare.get("offset"):
            facts["reference_median_offset_m"] = compare["offset"]["median_m"]
        match = results.get("match") or {}
        if match.get("median_m") is not None:
            facts["gnss_median_distance_m"] = match["median_m"]
            facts["gnss_matched_fraction"] = match["matched_fraction"]
        return StageOutput(files=files, facts=facts)

    def _validate(self, context, xodr, files) -> tuple[dict | None, object, list]:
        """(validation summary, the loaded map, the findings); a StageError when the file cannot be read as
        OpenDRIVE."""
        from tavf_mapkit.opendrive import load_opendrive
        from tavf_mapkit.pipeline.builtin.stage_map import take_kept_map

        try:
            from tavf_mapkit.validate.runner import validate_and_load
        except ImportError as error:
            context.note(f"validate not available: {error}")
            try:
                return None, load_opendrive(xodr), []
            except InputError as unreadable:
                raise StageError(f"the OpenDRIVE is unreadable: {unreadable}") from None
        try:
            # the mesh stage's map when it kept it (a small map, the same file): not loaded a second time
            report, odr, unreadable = validate_and_load(str(xodr), odr=take_kept_map(context),
                                                        snapshot=context.artifacts.get("odrmap"))
        except InputError as error:  # not even well-formed XML
            raise StageError(f"the OpenDRIVE is unreadable: {error}") from None
        if unreadable is not None:
            raise StageError(f"the OpenDRIVE is unreadable: {unreadable}")
        # the file as the build names it: the path read is in the staging folder, gone once the build is in place
        written = {**report.to_dict(), "file": xodr.name}
        context.output_path("report/validate.json").write_text(json.dumps(written, indent=2) + "\n", encoding="utf-8")
        files["validate_report"] = "report/validate.json"
        return {**report.summary, **_findings_by_rule(report)}, odr, list(report.findings)

    def _compare(self, context, xodr, reference, files) -> dict:
        from tavf_mapkit.accuracy.compare import compare_networks
        from tavf_mapkit.accuracy.plot import plot_comparison

        try:
            comparison = compare_networks(xodr, reference)
        except InputError as error:
            context.note(f"compare skipped: {error}")
            return {"error": str(error)}
        report = comparison.to_dict()
        report["build"] = xodr.name  # the staging folder's path would be a dead reference after the build
        context.output_path("report/compare.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
        plot_comparison(comparison, context.output_path("report/compare.png"))
        files.update({"compare_report": "report/compare.json", "compare_plot": "report/compare.png"})
        return report

    def _match(self, context, odr, trace_path, files) -> tuple[dict, tuple | None]:
        """(statistics, (trace, MatchResult) for the page's map, or None when the trace could not be matched)"""
        from tavf_mapkit.accuracy.matching import match_trace
        from tavf_mapkit.accuracy.plot import plot_match
        from tavf_mapkit.lanegraph import LaneGraph
        from tavf_mapkit.traces import read_trace

        try:
            trace = read_trace(trace_path)
            graph = LaneGraph.from_opendrive(odr)
            result = match_trace(odr, trace, graph)
        except InputError as error:
            context.note(f"match-trace skipped: {error}")
            return {"error": str(error)}, None
        stats = {"trace": str(trace_path), **result.stats()}
        context.output_path("report/match-trace.json").write_text(json.dumps(stats, indent=2) + "\n",
                                                                  encoding="utf-8")
        plot_match(result, graph, context.output_path("report/match-trace.png"),
                   title=f"{trace_path.name}: fixes by distance to the matched lane (m); unmatched: x")
        files.update({"match_report": "report/match-trace.json", "match_plot": "report/match-trace.png"})
        return stats, (trace, result)


def _roundtrip(odr) -> dict:
    """Largest distance after local -> WGS84 -> local of points spread over the map."""
    if odr.georeference is None:
        return {"roundtrip_m": None, "note": "no geoReference"}
    west, south, east, north = odr.bounds(step=10.0)
    x, y = np.meshgrid(np.linspace(west, east, 5), np.linspace(south, north, 5))
    lon, lat = odr.georeference.local_to_wgs84(x.ravel(), y.ravel())
    back_x, back_y = odr.georeference.wgs84_to_local(lon, lat)
    error = float(np.max(np.hypot(back_x - x.ravel(), back_y - y.ravel())))
    return {"roundtrip_m": round(error, 9), "points": int(x.size)}


def _findings_by_rule(report) -> dict:
    """Per severity the count of each rule, and each rule's first finding (where and what, for the page)."""
    from collections import Counter

    counts = {"error": Counter(), "warning": Counter(), "info": Counter()}
    first: dict[str, str] = {}
    for finding in report.findings:
        counts[finding.severity][finding.rule] += 1
        first.setdefault(finding.rule, str(finding).split(None, 2)[-1])  # without severity and rule id
    return {"errors_by_rule": dict(sorted(counts["error"].items())),
            "warnings_by_rule": dict(sorted(counts["warning"].items())),
            "info_by_rule": dict(sorted(counts["info"].items())), "first_by_rule": first}


def _validation_checks(validate: dict | None, limits: dict) -> list[dict]:
    """Checks on the validation findings: one per rule with its own limit, then errors and (when limited)
    warnings of all other rules. Without a validation report they cannot pass or fail (n/a)."""
    rules = limits.get("rules") or {}
    checks = []
    counts = {}
    if validate is not None:
        for key in ("errors_by_rule", "warnings_by_rule", "info_by_rule"):
            for rule, n in (validate.get(key) or {}).items():
                counts[rule] = counts.get(rule, 0) + n
    for rule, limit in sorted(rules.items()):
        value = counts.get(rule, 0) if validate is not None else None
        checks.append({"key": f"validation.rules.{rule}", "what": f"validation findings of {rule}",
                       "value": value, "limit": limit, "kind": "max",
                       "passed": None if value is None else value <= limit})
    for severity, key, default in (("errors", "max_errors", 0), ("warnings", "max_warnings", None)):
        limit = limits.get(key, default)
        if limit is None:
            continue
        value = None
        if validate is not None:
            by_rule = validate.get(f"{severity}_by_rule") or {}
            value = sum(n for rule, n in by_rule.items() if rule not in rules)
        what = f"validation {severity}" + (" (rules without their own limit)" if rules else "")
        checks.append({"key": f"validation.{key}", "what": what, "value": value, "limit": limit,
                       "kind": "max",
                       "passed": None if value is None else value <= limit})
    return checks


def _repairs(context: BuildContext) -> list[dict] | None:
    """The opendrive stage's repairs as rows; None when it recorded none at all (not even "none needed")."""
    repairs = (context.facts.get("opendrive") or {}).get("repairs")
    return None if repairs is None else repair_rows(repairs)


def repair_rows(repairs) -> list[dict]:
    """The repairs the opendrive stage recorded in its facts (``repairs``), as rows {repair, count, detail}.

    Read generically: a mapping {repair: count} or {repair: {count, ...}}, or a list of mappings with a name
    under ``repair``/``kind``/``name``; anything else of an entry is kept as its detail."""
    if isinstance(repairs, dict):
        entries = [{"repair": name, **(value if isinstance(value, dict) else {"count": value})}
                   for name, value in repairs.items()]
    elif isinstance(repairs, list):
        entries = [entry if isinstance(entry, dict) else {"repair": entry} for entry in repairs]
    else:
        return []
    rows = []
    for entry in entries:
        entry = dict(entry)
        name = next((entry.pop(key) for key in ("repair", "kind", "name") if key in entry), "repair")
        count = entry.pop("count", None)
        rows.append({"repair": str(name), "count": count, "detail": entry or None})
    return rows


def _evaluate(results: dict, thresholds: dict) -> list[dict]:
    checks = []
    for key, limit in thresholds.items():
        spec = THRESHOLDS.get(key)
        if spec is None:
            checks.append({"key": key, "what": "unknown threshold", "value": None, "limit": limit, "passed": None})
            continue
        source, what, getter, kind = spec
        data = results.get(source)
        value = None
        if data and "error" not in data:
            try:
                value = getter(data)
            except (KeyError, TypeError):
                value = None
        passed = None if value is None else (value <= limit if kind == "max" else value >= limit)
        checks.append({"key": key, "what": what, "value": value, "limit": limit, "kind": kind, "passed": passed})
    return checks


#: most lane samples the report's embedded map takes: each costs about 350 bytes while the map is made, and a
#: region's report must not hold the build's memory (Maribor, 1,985 km of lanes at 1 m: +690 MiB; at 5 m: +130)
REPORT_MAP_SAMPLES = 400_000


def report_map_step(odr) -> float:
    """Sampling step (m) of the report's lane and mark layers: the view's 1 m, coarser on maps with more lane
    length than REPORT_MAP_SAMPLES samples of it (``mapkit view`` keeps 1 m)."""
    import numpy as np

    from tavf_mapkit.view.mapdata import STEP_M

    arrays = odr.arrays
    lane_length = float(np.sum((arrays.section_end - arrays.section_s0)[arrays.lane_section]))
    return max(STEP_M, lane_length / REPORT_MAP_SAMPLES)


def _page_map(context, odr, findings: list, matched) -> tuple[str, str | list[str]]:
    """(head, body) of the page's 2D map (tavf_mapkit.view: the same map as ``mapkit view``), or a note
    when the map cannot be drawn (the check itself stands)."""
    from tavf_mapkit.errors import MapkitError
    from tavf_mapkit.pipeline.manifest import OSM_ATTRIBUTION
    from tavf_mapkit.pipeline.summary import derived_from_osm
    from tavf_mapkit.view.mapdata import map_json, repair_counts
    from tavf_mapkit.view.page import static_map_parts

    repairs = (context.facts.get("opendrive") or {}).get("repairs")
    attribution = OSM_ATTRIBUTION if derived_from_osm(context.input_path, context.input_kind) else None
    try:
        # as JSON text, made in batches of lanes: as dicts a city's map would hold hundreds of megabytes
        data = map_json(odr, name=context.name, findings=findings, repairs=repairs, match=matched,
                        attribution=attribution, step=report_map_step(odr),
                        extra={"repair_counts": repair_counts(repairs), "findings_total": len(findings)})
    except MapkitError as error:
        context.note(f"report map skipped: {error}")
        return "", f"<p>The map could not be drawn: {error}</p>"
    return static_map_parts(data)


def _html(results: dict, context, page_map: tuple[str, str | list[str]] = ("", "")) -> str:
    """One page, images and map embedded, no external resources: verdict, the 2D map (lanes, findings,
    repairs, GNSS), checks, findings per rule, repairs."""
    return "".join(_html_parts(results, context, page_map))


def _html_parts(results: dict, context, page_map: tuple[str, str | list[str]] = ("", "")) -> list[str]:
    """_html as pieces: before the map's body, the map's body (a string or its pieces), after it; so the page
    is written without a copy of the map."""
    import base64
    import html

    def cell(value) -> str:
        return f"<td>{html.escape('' if value is None else str(value))}</td>"

    rows = []
    for check in results["checks"]:
        state = {True: "pass", False: "FAIL", None: "n/a"}[check["passed"]]
        rows.append(f"<tr class='{state.lower().replace('/', '')}'>"
                    f"{cell(check['what'])}{cell(check['value'])}"
                    f"<td>{'&le;' if check.get('kind') == 'max' else '&ge;'} {check['limit']}</td>"
                    f"<td>{state}</td></tr>")
    validate = results.get("validate") or {}
    limits = {c["key"].removeprefix("validation.rules."): c for c in results["checks"]
              if c["key"].startswith("validation.rules.")}
    findings = []
    severities = (("error", "errors_by_rule"), ("warning", "warnings_by_rule"), ("info", "info_by_rule"))
    for severity, key in severities:
        for rule, count in sorted((validate.get(key) or {}).items(), key=lambda item: -item[1]):
            own = limits.get(rule)
            state = ("FAIL" if own and own["passed"] is False else "within its limit" if own else
                     "counted" if severity == "error" else "")
            findings.append(f"<tr class='{'fail' if state == 'FAIL' else severity}'>"
                            f"{cell(rule)}{cell(severity)}"
                            f"{cell(count)}{cell(own['limit'] if own else None)}{cell(state)}"
                            f"{cell((validate.get('first_by_rule') or {}).get(rule))}</tr>")
    def detail(entry: dict | None) -> str | None:
        if not entry:
            return None
        return "; ".join(f"{key}: {', '.join(map(str, value)) if isinstance(value, list) else value}"
                         for key, value in entry.items())

    repairs = [f"<tr>{cell(r['repair'])}{cell(r['count'])}{cell(detail(r['detail']))}</tr>"
               for r in results.get("repairs") or []]
    images = []
    for name, caption in (("compare.png", "build lanes by distance to the reference network"),
                          ("match-trace.png", "GNSS fixes by distance to their matched lane")):
        path = context.folder / "report" / name
        if path.exists():
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            images.append(f"<figure><img alt='{caption}' src='data:image/png;base64,{data}'>"
                          f"<figcaption>{caption}</figcaption></figure>")
    summary = (f"validation: {validate.get('errors')} errors, {validate.get('warnings')} warnings"
               if validate else "validation: not run")
    failed = [c for c in results["checks"] if c["passed"] is False]
    because = ("; failed: " + "; ".join(f"{c['what']} {c['value']} (limit {c['limit']})" for c in failed)
               if failed else "")
    findings_table = (f"<table><tr><th>rule</th><th>severity</th><th>findings</th><th>own limit</th><th></th>"
                      f"<th>first finding</th></tr>{''.join(findings)}</table>" if findings else
                      "<p>No findings.</p>" if validate else "<p>Validation did not run.</p>")
    repairs_table = (f"<table><tr><th>repair</th><th>count</th><th>detail</th></tr>{''.join(repairs)}</table>"
                     if repairs else "<p>None were needed.</p>" if results.get("repairs") is not None else
                     "<p>None recorded by the opendrive stage.</p>")
    status = results["status"]
    before = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>check: {html.escape(results['file'])}: {status}</title>
<style>body{{font:14px sans-serif;margin:2em;max-width:70em}}td,th{{padding:.2em .8em;text-align:left}}
tr.fail td,tr.error td{{color:#b00}}tr.fail td{{font-weight:bold}}tr.pass td:last-child{{color:#070}}
h1.fail,h1.unchecked{{color:#b00}}h1.pass{{color:#070}}img{{max-width:100%}}</style>{page_map[0]}</head>
<body><h1 class='{status}'>Check of {html.escape(results['file'])}: {status.upper()}</h1>
<p>{html.escape(summary + because)}; georeference round trip {results['georeference'].get('roundtrip_m')} m.
Details: check.json, validate.json, compare.json, match-trace.json in this folder.</p>
<h2>Map</h2>
<p>Lanes by type, junction outlines, road marks, signals and objects; every validation finding as a marker
(click it: rule, road, lane, s); the roads the build repaired; the GNSS trace and its matched path. The same
map with the 3D view and drive replays: <code>mapkit view BUILD [RUN ...]</code>.</p>
"""
    after = f"""
<h2>Checks</h2>
<table><tr><th>check</th><th>value</th><th>threshold</th><th></th></tr>{''.join(rows)}</table>
<h2>Validation findings by rule</h2>
{findings_table}
<h2>Repairs of the OpenDRIVE</h2>
{repairs_table}
{''.join(images)}
</body></html>
"""
    body = page_map[1]
    return [before, *([body] if isinstance(body, str) else body), after]
