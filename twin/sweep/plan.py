"""What a sweep runs: its seeds and the ``twin drive`` options every run shares."""

from __future__ import annotations

import re
from dataclasses import dataclass

from tavf_mapkit.errors import InputError

MAX_SEEDS = 100_000
_PART = re.compile(r"(\d+)(?:-(\d+))?")


def parse_seeds(text: str) -> list[int]:
    """"0-199", "3", "0-9,20,40-41" -> ascending distinct seeds; a one-line InputError for anything else."""
    seeds: set[int] = set()
    for part in text.split(","):
        match = _PART.fullmatch(part.strip())
        if match is None:
            raise InputError(f"--seeds {text!r}: expected seeds such as 0-199 or 1,5,9-12")
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) is not None else first
        if last < first:
            raise InputError(f"--seeds {text!r}: range {part.strip()} runs backwards")
        if last - first + 1 + len(seeds) > MAX_SEEDS:
            raise InputError(f"--seeds {text!r}: more than {MAX_SEEDS} runs")
        seeds.update(range(first, last + 1))
    return sorted(seeds)


@dataclass(frozen=True)
class DriveOptions:
    """The options of every run's ``twin drive --random``; only the seed differs between runs."""

    duration: float = 60.0
    traffic: int = 0
    udm: str | None = None
    udm_realtime: bool = False  # each run's UDM client process under SCHED_FIFO (twin drive --udm-realtime)
    pace: float | None = None
    dt: float = 0.05

    def arguments(self, seed: int) -> list[str]:
        args = ["--random", "--duration", repr(float(self.duration)), "--seed", str(int(seed)),
                "--dt", repr(float(self.dt)), "--no-plot", "--no-record", "--json"]
        if self.traffic:
            args += ["--traffic", str(int(self.traffic))]
        if self.udm:
            args += ["--udm", self.udm]
            if self.udm_realtime:
                args.append("--udm-realtime")
        if self.pace is not None:
            args += ["--pace", repr(float(self.pace))]
        return args

    def deadline(self) -> float:
        """Seconds a run may take before it is killed: the map's set-up, then the drive (at real time when
        paced) with room for a machine shared with other runs."""
        pace = self.pace or 4.0  # unpaced drives run far faster than this; 4x is a slow machine's floor
        return 300.0 + 3.0 * self.duration / pace
