"""Stages that run beside others: a later stage starts in a process of its own as soon as its inputs exist.

The check stage reads only NAME.xodr (and the opendrive stage's facts); the mesh and collision stages between
them neither make nor change it. One process runs the stages in pipeline order, so on a region the validation
(minutes) waited for the tile stages although a second core was idle. A stage that says ``runs_beside``
starts in a child process once every stage between it and the one running makes none of its inputs (each
declares what it ``makes``; one that does not declare it keeps every later stage behind it), and the runner
takes its result when the pipeline reaches it: its record, notes and files are what running it there would
have given (the fingerprint is computed again at that point; a different one discards the early run).

The child is spawned, not forked (a build with ``--workers`` has Dask's threads in the client), ignores
Ctrl-C (the runner stops it when the build ends any other way than by taking its result) and sends back its
StageOutput, its notes and the error it raised, if any, which the runner raises where the stage would have.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
import time
import traceback
from pathlib import Path

from tavf_mapkit.errors import MapkitError, StageError
from tavf_mapkit.pipeline.manifest import path_bytes
from tavf_mapkit.progress import silent

#: a stage starts beside others only when its input files are at least this large in all: below it the child's
#: start (imports, its own map load) costs about what it saves (the sample, a district)
MIN_INPUT_BYTES = 8 << 20


#: cores to spare for it: the load average counts the build itself (about 1.0 while a stage runs on a quiet
#: 2-core machine, 2 and more beside another job)
IDLE_CORES = 0.5


def idle_cores() -> float:
    """Cores this process may use beyond the one it runs on, less the machine's load (its last minute's average,
    this build included): on a busy machine a second process only competes with the first and costs its start."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = 1.0
    return cores - max(load, 1.0)


def may_start(stages: list, position: int, candidate: int, context) -> bool:
    """Whether ``stages[candidate]`` may start now, while ``stages[position]`` is about to run: it runs beside
    others, every stage from ``position`` up to it declares what it makes and none makes one of its inputs,
    and its inputs exist and are large enough to be worth a process."""
    stage = stages[candidate]
    if stage is None or not stage.runs_beside or context.input_kind not in stage.input_kinds:
        return False
    reads = {*stage.inputs, *stage.optional_inputs}
    for between in stages[position:candidate]:
        if between is None:
            continue
        if between.makes is None or reads.intersection(between.makes):
            return False
    if any(name not in context.artifacts for name in stage.inputs):
        return False
    size = sum(_bytes(context.artifacts[name]) for name in reads if name in context.artifacts)
    return size >= MIN_INPUT_BYTES and idle_cores() >= IDLE_CORES


def _bytes(path: Path) -> int:
    return path_bytes(path) if Path(path).exists() else 0


def _no_notes(message: str) -> None:
    """The notify of a context on its way to a child (which collects its notes itself)."""


class BesideStage:
    """A stage running in a child process; ``result()`` waits for it, ``stop()`` ends it."""

    def __init__(self, stage, context, fingerprint: str):
        self.stage, self.fingerprint = stage, fingerprint
        copy = dataclasses.replace(context, notify=_no_notes, progress=silent, fanout=None, kept_map=None, running_beside=set(),
                                   artifacts=dict(context.artifacts), facts=dict(context.facts))
        spawn = multiprocessing.get_context("spawn")
        self._receive, send = spawn.Pipe(duplex=False)
        self._process = spawn.Process(target=_run_in_child, args=(stage, copy, send), daemon=True,
                                      name=f"mapkit stage {stage.name}")
        self._process.start()
        send.close()  # the child's end: when the child dies, recv() sees the pipe closed instead of waiting

    def result(self, note):
        """(StageOutput, seconds) of the stage, its notes passed to ``note`` first; raises what it raised."""
        try:
            outcome, value, notes, seconds = self._receive.recv()
        except EOFError:
            self._process.join()
            raise StageError(f"stage {self.stage.name} ended without a result (its process exited with code "
                             f"{self._process.exitcode})") from None
        finally:
            self._receive.close()
        self._process.join()
        for line in notes:
            note(line)
        if outcome == "error":
            raise value
        if outcome == "crash":
            raise RuntimeError(f"stage {self.stage.name} failed in its own process:\n{value}")
        return value, seconds

    def stop(self) -> None:
        if self._process.is_alive():
            self._process.kill()
        self._process.join()
        self._receive.close()


def _run_in_child(stage, context, send) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the runner ends this process; Ctrl-C is the runner's
    notes: list[str] = []
    context.notify = notes.append
    started = time.perf_counter()
    try:
        payload = ("ok", stage.run(context))
    except (MapkitError, OSError) as error:
        payload = ("error", error)
    except BaseException:  # noqa: BLE001 -- a bug: its traceback goes to the runner, which raises it
        payload = ("crash", traceback.format_exc())
    send.send((*payload, notes, time.perf_counter() - started))
    send.close()
