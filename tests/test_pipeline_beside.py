"""Stages beside others (pipeline/beside.py): the check stage validating in a process of its own while the tile
stages run writes what it writes in its turn; its errors surface in its turn; a build that fails or is stopped
before reaching it ends its process."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from tavf_mapkit.errors import StageError
from tavf_mapkit.pipeline import beside
from tavf_mapkit.pipeline.config import PipelineConfig
from tavf_mapkit.pipeline.runner import run_build
from tavf_mapkit.pipeline.stages import Stage, StageOutput, register_stage, unregister_stage

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "tavf_synthetic.osm"


@pytest.fixture
def allow_beside(monkeypatch):
    """Stages run beside others whatever the map's size and the machine's load."""
    monkeypatch.setattr(beside, "MIN_INPUT_BYTES", 0)
    monkeypatch.setattr(beside, "idle_cores", lambda: 1.0)


def files_of(folder: Path) -> dict[str, bytes]:
    """The build's files that depend on its input alone (netconvert stamps its files with the time; the snapshot
    names the folder it was made in)."""
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*"))
            if path.is_file() and path.name != "manifest.json" and path.suffix != ".odrmap"
            and not path.name.endswith(".net.xml") and path.parent.name not in ("netconvert", "logs")}


def records(folder: Path) -> dict[str, dict]:
    return {record["name"]: record for record in json.loads((folder / "manifest.json").read_text())["stages"]}


def test_the_check_stage_beside_the_tile_stages_writes_what_it_writes_in_turn(tmp_path, monkeypatch):
    lines_in_turn, lines_beside = [], []
    monkeypatch.setattr(beside, "MIN_INPUT_BYTES", 1 << 62)
    in_turn = run_build(SAMPLE, PipelineConfig(), tmp_path / "in-turn" / "sample", progress=lines_in_turn.append)
    monkeypatch.setattr(beside, "MIN_INPUT_BYTES", 0)
    monkeypatch.setattr(beside, "idle_cores", lambda: 1.0)
    early = run_build(SAMPLE, PipelineConfig(), tmp_path / "beside" / "sample", progress=lines_beside.append)
    assert records(early.folder)["check"].get("beside") is True
    assert "beside" not in records(in_turn.folder)["check"]
    assert files_of(early.folder) == files_of(in_turn.folder)
    for name in ("check", "report"):  # facts and outputs as in turn
        assert {key: records(early.folder)[name][key] for key in ("facts", "outputs")} == \
               {key: records(in_turn.folder)[name][key] for key in ("facts", "outputs")}
    assert any(line.startswith("[6/7] check: ran in ") and line.endswith(" s beside the stages before it")
               for line in lines_beside)
    # the notes it made in its process reach the user, in the same words, in its turn
    notes = [line for line in lines_in_turn if not line.startswith("[")]
    assert notes and notes == [line for line in lines_beside if not line.startswith("[")]
    # unchanged input: every stage reused, none started early
    again = run_build(SAMPLE, PipelineConfig(), early.folder)
    assert {record["status"] for record in records(again.folder).values()} == {"unchanged"}


class FailsBeside(Stage):
    makes = ()
    runs_beside = True
    inputs = ("xodr",)

    def run(self, context):
        (context.folder / "report").mkdir(exist_ok=True)
        raise StageError("the reference network is not a network", file="report/x.json", line=3)


class WaitsBeside(Stage):
    makes = ()
    runs_beside = True
    inputs = ("xodr",)

    def run(self, context):
        (context.folder / "beside.pid").write_text(str(os.getpid()))
        time.sleep(120)
        return StageOutput()


class FailsInTurn(Stage):
    makes = ()
    inputs = ("xodr",)

    def run(self, context):
        deadline = time.monotonic() + 60
        while not (context.folder / "beside.pid").exists() and time.monotonic() < deadline:
            time.sleep(0.05)  # the stage beside it has started
        raise StageError("mesh failed on purpose")


@pytest.fixture
def test_stages():
    names = {"fails_beside": FailsBeside, "waits_beside": WaitsBeside, "fails_in_turn": FailsInTurn}
    for name, cls in names.items():
        register_stage(name)(cls)
    yield
    for name in names:
        unregister_stage(name)


def test_an_error_beside_is_raised_in_the_stages_turn(tmp_path, allow_beside, test_stages):
    lines = []
    config = PipelineConfig(stages=("extract", "netconvert", "opendrive", "mesh", "fails_beside", "report"))
    with pytest.raises(StageError) as raised:
        run_build(SAMPLE, config, tmp_path / "sample", progress=lines.append)
    assert str(raised.value) == "report/x.json:3: the reference network is not a network"
    assert any(line.startswith("[4/6] mesh: ran in") for line in lines)  # the stage before it finished first
    assert not (tmp_path / "sample").exists() and not list(tmp_path.glob(".sample.staging-*"))


def test_a_build_that_fails_before_a_stage_beside_ends_its_process(tmp_path, allow_beside, test_stages):
    config = PipelineConfig(stages=("extract", "netconvert", "opendrive", "fails_in_turn", "waits_beside"))
    started = time.monotonic()
    pid_seen = []
    real_stop = beside.BesideStage.stop

    def stop(self):
        staging = next(tmp_path.glob(".sample.staging-*"))
        pid_seen.append(int((staging / "beside.pid").read_text()))
        real_stop(self)

    beside.BesideStage.stop = stop
    try:
        with pytest.raises(StageError, match="mesh failed on purpose"):
            run_build(SAMPLE, config, tmp_path / "sample")
    finally:
        beside.BesideStage.stop = real_stop
    assert time.monotonic() - started < 60  # not the 120 s the stage beside would have taken
    assert len(pid_seen) == 1
    with pytest.raises(ProcessLookupError):
        os.kill(pid_seen[0], 0)  # ended and reaped


def test_a_stage_after_one_that_does_not_say_what_it_makes_waits_its_turn(tmp_path, allow_beside, test_stages):
    class Undeclared(Stage):
        inputs = ("xodr",)

        def run(self, context):
            return StageOutput()

    register_stage("undeclared")(Undeclared)
    try:
        config = PipelineConfig(stages=("extract", "netconvert", "opendrive", "undeclared", "check"))
        result = run_build(SAMPLE, config, tmp_path / "sample")
    finally:
        unregister_stage("undeclared")
    assert "beside" not in records(result.folder)["check"]
    config = PipelineConfig(stages=("extract", "netconvert", "opendrive", "collision", "check"))
    result = run_build(SAMPLE, config, tmp_path / "declared")
    assert records(result.folder)["check"].get("beside") is True
