"""Routes as lanes -> dense polylines ("chunks") the path buffer consumes."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from tavf_mapkit.errors import MapkitError
from tavf_mapkit.lanegraph import LaneKey
from twin.map.lanelines import LaneLines

DEFAULT_SPEED = 50.0 / 3.6  # m/s when the map sets no limit (urban default)
LANE_CHANGE_MAX = 25.0  # m of a lane change manoeuvre at most
# netconvert writes sub-metre connecting roads whose heading is numerically meaningless, so their lanes can
# lie metres to the wrong side; such lanes add no points and the path joins their neighbours directly
DEGENERATE_LANE = 1.0
# a route that adds no point to its path for this many lanes in a row has stalled (lanes of sub-metre
# connecting roads only): it raises instead of being asked for more for ever
MAX_EMPTY_LANES = 1000


class RouteStalled(MapkitError):
    """A route that cannot advance: it would loop for ever without covering distance."""


@dataclass(frozen=True)
class RouteBreak:
    """An item of a lane route between two lanes that do not join: the car turns around onto the next lane
    ("turnaround") or is put on a new route ("restart")."""

    kind: str


TURNAROUND = RouteBreak("turnaround")
RESTART = RouteBreak("restart")


@dataclass(frozen=True, eq=False)
class PathChunk:
    """A stretch of path: points (n, 3), the speed limit and the lane (index into a LaneCodes) per point.
    ``begins``: None, or the kind of ``RouteBreak`` that separates this chunk from the path before it."""

    points: np.ndarray
    speed_limit: np.ndarray
    lane_code: np.ndarray
    begins: str | None = None

    def __len__(self) -> int:
        return len(self.points)

    @staticmethod
    def concat(chunks: Sequence[PathChunk]) -> PathChunk:
        return PathChunk(np.concatenate([c.points for c in chunks]), np.concatenate([c.speed_limit for c in chunks]),
                         np.concatenate([c.lane_code for c in chunks]), chunks[0].begins if chunks else None)

    def slice(self, start: int, stop: int | None = None) -> PathChunk:
        return PathChunk(self.points[start:stop], self.speed_limit[start:stop], self.lane_code[start:stop],
                         self.begins)


class LaneCodes:
    """Lane keys <-> small integers, so paths can carry the lane of every point in an int array."""

    def __init__(self, graph):
        self.graph = graph
        self.keys: list[LaneKey] = []
        self._codes: dict[LaneKey, int] = {}
        self.road_ids: list[str] = []

    def code(self, key: LaneKey) -> int:
        found = self._codes.get(key)
        if found is None:
            found = self._codes[key] = len(self.keys)
            self.keys.append(key)
            self.road_ids.append(self.graph.road_id(key))
        return found

    def road_id(self, code: int) -> str:
        return self.road_ids[code]

    def lane_id(self, code: int) -> int:
        return self.keys[code].lane_id


def lane_chunk(lines: LaneLines, codes: LaneCodes, key: LaneKey, start: float = 0.0,
               stop: float | None = None) -> PathChunk:
    """The lane's centre line from ``start`` to ``stop`` metres along it."""
    line = lines[key]
    if line.length < DEGENERATE_LANE:
        return PathChunk(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64))
    stop = line.length if stop is None else stop
    keep = (line.along >= start - 1e-9) & (line.along <= stop + 1e-9)
    points = line.points[keep]
    if len(points) == 0:  # a window between two samples: its nearest sample keeps the path continuous
        points = line.points[[int(np.argmin(np.abs(line.along - 0.5 * (start + stop))))]]
    limit = line.speed_limit if line.speed_limit else DEFAULT_SPEED
    return PathChunk(points, np.full(len(points), limit), np.full(len(points), codes.code(key)))


@dataclass(frozen=True)
class Span:
    """Lane ``key`` (position ``index`` in its route) from ``start`` to ``stop`` metres along (None: the end)."""

    index: int
    key: LaneKey
    start: float
    stop: float | None


def route_spans(lines: LaneLines, graph, route: Iterable[LaneKey | RouteBreak],
                first_along: float = 0.0) -> Iterator[Span | RouteBreak]:
    """The stretch of each lane a route drives (any iterable, also endless). A run of lane changes inside one
    lane section splits that section between the lanes, each transition a straight diagonal of up to
    ``LANE_CHANGE_MAX`` metres. The first lane starts ``first_along`` metres in. ``RouteBreak`` items pass
    through; a run of lane changes that comes back to a lane of the run raises ``RouteStalled`` (it would
    split one section between ever more lanes and never reach the next)."""
    keys = iter(route)
    pending = next(keys, None)
    index = 0
    first = True
    while pending is not None:
        if isinstance(pending, RouteBreak):
            yield pending
            pending = next(keys, None)
            continue
        run = [pending]
        pending = next(keys, None)
        while isinstance(pending, LaneKey) and graph.edge_kind(run[-1], pending) not in (None, "follow"):
            if pending in run:
                raise RouteStalled(f"the route changes lanes in a circle on road {graph.road_id(pending)} "
                                   f"(lanes {', '.join(str(k.lane_id) for k in run)}, {pending.lane_id}) "
                                   "without driving on")
            run.append(pending)
            pending = next(keys, None)
        offset = first_along if first else 0.0
        first = False
        if len(run) == 1:
            yield Span(index, run[0], offset, None)
            index += 1
            continue
        length = min(lines[key].length for key in run)
        offset = min(offset, 0.5 * length)
        part = (length - offset) / len(run)
        gap = min(LANE_CHANGE_MAX, 0.6 * part)
        for j, key in enumerate(run):
            scale = lines[key].length / max(length, 1e-9)
            start = offset if j == 0 else (offset + j * part + 0.5 * gap) * scale
            stop = None if j == len(run) - 1 else (offset + (j + 1) * part - 0.5 * gap) * scale
            yield Span(index, key, start, stop)
            index += 1


def expand_route(lines: LaneLines, codes: LaneCodes, route: Iterable[LaneKey | RouteBreak],
                 first_along: float = 0.0) -> Iterator[PathChunk]:
    """Chunks of a lane route (see ``route_spans``). The first chunk with points after a ``RouteBreak``
    carries its kind in ``begins``. Raises ``RouteStalled`` after ``MAX_EMPTY_LANES`` lanes in a row
    without a point."""
    begins = None
    empty = 0
    for span in route_spans(lines, codes.graph, route, first_along):
        if isinstance(span, RouteBreak):
            begins = span.kind
            continue
        chunk = lane_chunk(lines, codes, span.key, span.start, span.stop)
        if not len(chunk):
            empty += 1
            if empty >= MAX_EMPTY_LANES:
                raise RouteStalled(f"the route drove {empty} lanes in a row without covering a metre (last: road "
                                   f"{codes.graph.road_id(span.key)} lane {span.key.lane_id})")
            continue
        empty = 0
        if begins is not None:
            chunk = PathChunk(chunk.points, chunk.speed_limit, chunk.lane_code, begins)
            begins = None
        yield chunk


def with_speed(chunks: Iterable[PathChunk], speed: float | None) -> Iterator[PathChunk]:
    """The chunks with a fixed target speed (m/s) in place of their own; unchanged when ``speed`` is None."""
    for chunk in chunks:
        if speed is None:
            yield chunk
        else:
            yield PathChunk(chunk.points, np.full(len(chunk), float(speed)), chunk.lane_code, chunk.begins)
