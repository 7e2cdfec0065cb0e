"""Stage "check": validate the OpenDRIVE, check the georeference round trip, and measure the build against
the references the pipeline file names ([check] reference_network_path, gnss_trace_path) with the
thresholds of [check.thresholds]. Writes report/check.json, report/validate.json, report/compare.json,
report/match-trace.json, PNG plots and report/index.html (one self-contained page).

A threshold that is not met is reported (facts, check.json, the page), not fatal: the build is still usable,
and CI guards accuracy through the baselines of tests/test_accuracy_regression.py.
"""

from __future__ import annotations

import json

import numpy as np

from tavf_mapkit.errors import InputError, StageError
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
    inputs = ("xodr",)
    version = "2"  # 2: compare.json names the xodr by file name
    description = "validate, georeference round trip, compare / match-trace against the pipeline's references"

    def options(self, context: BuildContext) -> dict:
        return {"check": context.section("check")}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.opendrive import load_opendrive

        section = context.section("check")
        thresholds = section.get("thresholds", {}) or {}
        xodr = context.artifacts["xodr"]
        try:
            odr = load_opendrive(xodr)
        except InputError as error:
            raise StageError(f"the OpenDRIVE is unreadable: {error}") from None
        files: dict[str, str] = {}
        results: dict = {"file": xodr.name}
        results["validate"] = self._validate(context, xodr, files)
        results["georeference"] = _roundtrip(odr)
        reference = section.get("reference_network_path")
        if reference is not None:
            results["compare"] = self._compare(context, xodr, reference, files)
        trace = section.get("gnss_trace_path")
        if trace is not None:
            results["match"] = self._match(context, odr, trace, files)
        checks = _evaluate(results, thresholds)
        results["checks"] = checks
        failed = [c for c in checks if c["passed"] is False]
        results["status"] = "fail" if failed else "pass"
        for check in failed:
            context.note(f"check failed: {check['what']} = {check['value']} (threshold {check['limit']})")
        path = context.output_path("report/check.json")
        path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
        files["check_report"] = "report/check.json"
        html = context.output_path("report/index.html")
        html.write_text(_html(results, context), encoding="utf-8")
        files["check_html"] = "report/index.html"
        validate = results["validate"] or {}
        facts = {
            "status": results["status"], "failed": [c["key"] for c in failed],
            "validate_errors": validate.get("errors"), "validate_warnings": validate.get("warnings"),
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

    def _validate(self, context, xodr, files) -> dict | None:
        try:
            from tavf_mapkit.validate import validate_file
        except ImportError as error:
            context.note(f"validate not available: {error}")
            return None
        report = validate_file(str(xodr))
        context.output_path("report/validate.json").write_text(json.dumps(report.to_dict(), indent=2) + "\n",
                                                               encoding="utf-8")
        files["validate_report"] = "report/validate.json"
        return dict(report.summary)

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

    def _match(self, context, odr, trace_path, files) -> dict:
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
            return {"error": str(error)}
        stats = {"trace": str(trace_path), **result.stats()}
        context.output_path("report/match-trace.json").write_text(json.dumps(stats, indent=2) + "\n",
                                                                  encoding="utf-8")
        plot_match(result, graph, context.output_path("report/match-trace.png"),
                   title=f"{trace_path.name}: fixes by distance to the matched lane (m); unmatched: x")
        files.update({"match_report": "report/match-trace.json", "match_plot": "report/match-trace.png"})
        return stats


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


def _html(results: dict, context) -> str:
    """One small page, images embedded, no external resources."""
    import base64
    import html

    rows = []
    for check in results["checks"]:
        state = {True: "pass", False: "FAIL", None: "n/a"}[check["passed"]]
        rows.append(f"<tr class='{state.lower().replace('/', '')}'><td>{html.escape(check['what'])}</td>"
                    f"<td>{check['value']}</td><td>{'&le;' if check.get('kind') == 'max' else '&ge;'} "
                    f"{check['limit']}</td><td>{state}</td></tr>")
    images = []
    for name, caption in (("compare.png", "build lanes by distance to the reference network"),
                          ("match-trace.png", "GNSS fixes by distance to their matched lane")):
        path = context.folder / "report" / name
        if path.exists():
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            images.append(f"<figure><img alt='{caption}' src='data:image/png;base64,{data}'>"
                          f"<figcaption>{caption}</figcaption></figure>")
    validate = results.get("validate") or {}
    summary = (f"validate: {validate.get('errors')} errors, {validate.get('warnings')} warnings"
               if validate else "validate: not run")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>check: {html.escape(results['file'])}</title>
<style>body{{font:14px sans-serif;margin:2em;max-width:60em}}td,th{{padding:.2em .8em;text-align:left}}
tr.fail td{{color:#b00;font-weight:bold}}tr.pass td:last-child{{color:#070}}img{{max-width:100%}}</style></head>
<body><h1>Accuracy check of {html.escape(results['file'])}: {results['status']}</h1>
<p>{html.escape(summary)}; georeference round trip {results['georeference'].get('roundtrip_m')} m.
Details: check.json, validate.json, compare.json, match-trace.json in this folder.</p>
<table><tr><th>check</th><th>value</th><th>threshold</th><th></th></tr>{''.join(rows)}</table>
{''.join(images)}
</body></html>
"""
