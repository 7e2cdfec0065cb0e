"""Progress of long work: units done of a total, elapsed time and an estimate of the time left.

Work reports, the command decides what is shown. A stage asks its BuildContext for a report function per kind
of unit it counts -- ``report = context.progress("tiles")`` -- and calls ``report(done, total)`` as it goes;
library functions take the same factory as ``progress=`` (None: nobody watches). A report is at most a clock
read and a comparison, so the work costs the same whether anyone watches, and what it makes never depends
on it.

Who watches is the command's decision (``progress_line``): a person at a terminal gets one line on stderr that
overwrites itself at most ``INTERVAL`` apart; ``--json``, ``-q`` and a stderr that is a file or a pipe get
nothing, so logs and machine output never hold carriage returns.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import TextIO

#: ``report(done, total)``: ``done`` of ``total`` units of one kind of work are finished
Report = Callable[[int, int], None]
#: the unit counted ("tiles", "curves") -> the Report for that work; one per pass over the map
Progress = Callable[[str], Report]

#: seconds between two renders (at most 4 a second): a terminal never slows the work it shows
INTERVAL = 0.25
#: columns when the terminal does not say (the line is cut to the width so that it never wraps)
DEFAULT_COLUMNS = 80


def no_report(done: int, total: int) -> None:
    """The Report of work nobody watches."""


def silent(unit: str) -> Report:
    """The Progress of work nobody watches."""
    return no_report


def reporter(progress: Progress | None, unit: str) -> Report:
    """The Report for ``unit`` of an optional Progress (library functions take ``progress=None``)."""
    return no_report if progress is None else progress(unit)


def duration(seconds: float) -> str:
    """m:ss, or h:mm:ss from an hour on."""
    whole = max(0, int(round(seconds)))
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def format_progress(label: str, unit: str, done: int, total: int, elapsed: float, unit_elapsed: float) -> str:
    """``[4/7] mesh: 120/480 tiles (25%), 0:12 elapsed, about 0:36 left``. ``elapsed`` counts from the start
    of the task (the stage), ``unit_elapsed`` from the first report of this unit; the estimate assumes the
    units left take as long as the ones done, and is rounded up (never "0:00 left" before the end)."""
    share = f" ({100 * done // total}%)" if total > 0 else ""
    text = f"{label}: {done}/{total} {unit}{share}, {duration(elapsed)} elapsed"
    if 0 < done < total and unit_elapsed > 0:
        return f"{text}, about {duration(math.ceil(unit_elapsed * (total - done) / done))} left"
    return f"{text}, estimating time left" if done < total else text


class ProgressLine:
    """One line on a terminal that each render overwrites (carriage return, spaces over a longer old line: no
    escape codes, so a dumb terminal shows it too). Renders are at least ``interval`` seconds apart; reports
    in between are dropped, the next one shows the state then. ``clock`` is injectable for tests."""

    def __init__(self, stream: TextIO, *, clock: Callable[[], float] = time.monotonic,
                 interval: float = INTERVAL, columns: int | None = None):
        self.stream = stream
        self.clock = clock
        self.interval = interval
        self.columns = columns
        self.renders = 0
        self._last = -math.inf
        self._shown = 0  # characters of the live line now on the terminal (0: none)

    def task(self, label: str) -> Progress:
        """The Progress of one task named ``label`` (e.g. "[4/7] mesh"); its elapsed time counts from now."""
        started = self.clock()

        def progress(unit: str) -> Report:
            unit_started = self.clock()

            def report(done: int, total: int) -> None:
                now = self.clock()
                if now - self._last < self.interval:
                    return
                self._last = now
                self._render(format_progress(label, unit, int(done), int(total), now - started,
                                             now - unit_started))

            return report

        return progress

    def print(self, line: str) -> None:
        """A lasting line (a stage finished, a note): the live line makes room for it and comes back with the
        next render."""
        self.clear()
        self.stream.write(line + "\n")
        self.stream.flush()

    def clear(self) -> None:
        if self._shown:
            self.stream.write("\r" + " " * self._shown + "\r")
            self.stream.flush()
            self._shown = 0

    def _render(self, text: str) -> None:
        text = text[:max(1, self._columns() - 1)]  # never wrap: a wrapped line cannot be overwritten
        self.stream.write("\r" + text + " " * max(0, self._shown - len(text)))
        self.stream.flush()
        self._shown = len(text)
        self.renders += 1

    def _columns(self) -> int:
        if self.columns is not None:
            return self.columns
        try:
            return os.get_terminal_size(self.stream.fileno()).columns or DEFAULT_COLUMNS
        except (OSError, ValueError, AttributeError):
            return DEFAULT_COLUMNS


def progress_line(stream: TextIO, *, quiet: bool = False, as_json: bool = False) -> ProgressLine | None:
    """A ProgressLine on ``stream`` when a person watches it: a terminal, neither ``-q`` nor ``--json``."""
    if quiet or as_json:
        return None
    try:
        if not stream.isatty():
            return None
    except (AttributeError, ValueError):  # no isatty, or closed
        return None
    return ProgressLine(stream)
