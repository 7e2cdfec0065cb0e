"""Stage "report": report/summary.json (and .txt) -- what the build holds, in one place, for people and CI."""

from __future__ import annotations

import json

from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage


@register_stage("report")
class ReportStage(Stage):
    makes = ("report", "report_text")
    inputs = ()
    optional_inputs = ("source", "net", "xodr", "xodr_counts")
    version = "1"
    description = "one-screen summary and report/summary.json"

    def options(self, context: BuildContext) -> dict:
        # the facts of earlier stages are what the report shows, so they decide whether it is up to date
        return {"facts": {name: facts for name, facts in context.facts.items() if name != self.name}}

    def run(self, context: BuildContext) -> StageOutput:
        from tavf_mapkit.pipeline.summary import build_report, report_text

        report = build_report(context)
        context.output_path("report/summary.json").write_text(json.dumps(report, indent=2) + "\n",
                                                               encoding="utf-8")
        context.output_path("report/summary.txt").write_text(report_text(report) + "\n", encoding="utf-8")
        facts = {"roads": report.get("opendrive", {}).get("roads")}
        # the two files, not the folder: other stages write their own reports into report/ too
        return StageOutput(files={"report": "report/summary.json", "report_text": "report/summary.txt"},
                           facts=facts)
