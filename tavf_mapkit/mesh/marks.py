"""Road marks as thin ribbons a few millimetres above the lane surface, botts dots as small boxes.

A lane's road mark lies on its outer border (the centre lane's on the lane offset line). Supported types:
solid, broken, solid solid, solid broken, broken solid, broken broken, botts dots, and any type with explicit
``<type><line>`` / ``<explicit><line>`` records (length, space, tOffset, sOffset, width, colour). "curb",
"grass", "edge", "none" and "custom" without lines paint nothing (curbs are solids, not paint).

Defaults where the file says nothing: width 0.12 m (weight "standard") or 0.25 m ("bold"); broken lines
3 m paint / 6 m gap (German urban guide lines), phase starting at the record's s; double lines have a gap of
one line width between them, the first named line on the left (+t) side; botts dots 0.1 m square, 0.02 m high,
every 1 m.

Colour: ``RoadMarkMesh.colour`` holds a per-face index into ``MARK_COLOURS`` (``standard`` is white).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.mesh.adaptive import AdaptiveSamples
from tavf_mapkit.mesh.cleanup import face_cross, proper_faces
from tavf_mapkit.mesh.evaluate import reference_frames
from tavf_mapkit.mesh.exact import search_pairs
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.opendrive.borders import border_offsets

MARK_COLOURS = ("white", "yellow", "red", "blue", "green", "orange", "violet", "black")
LIFT = 0.005             # m above the lane surface
DEFAULT_WIDTH = {"bold": 0.25}
STANDARD_WIDTH = 0.12
BROKEN = (3.0, 6.0)      # m paint, m gap
DOT_SIZE, DOT_HEIGHT, DOT_SPACING = 0.1, 0.02, 1.0
NO_PAINT = {"none", "curb", "grass", "edge", "custom", ""}


@dataclass(frozen=True, eq=False)
class RoadMarkMesh(LabelledMesh):
    """Road-mark triangles with a per-face colour index into ``MARK_COLOURS``."""

    colour: np.ndarray | None = None  # (M,) int8

    def _rebuilt(self, vertices, faces, face_index, uv):
        base = LabelledMesh._rebuilt(self, vertices, faces, face_index, uv)
        return RoadMarkMesh(base.vertices, base.faces, base.road_index, base.lane_id, base.kind, base.uv,
                            self.colour[face_index])

    @classmethod
    def empty(cls) -> RoadMarkMesh:
        base = LabelledMesh.empty()
        return cls(base.vertices, base.faces, base.road_index, base.lane_id, base.kind, base.uv,
                   np.zeros(0, dtype=np.int8))


def colour_index(name: str | None) -> int:
    name = (name or "standard").lower()
    return MARK_COLOURS.index(name) if name in MARK_COLOURS else 0


@dataclass
class _Lines:
    """Mark lines to paint, one row each (built by a loop over the map's road-mark records)."""

    road: list
    row: list       # lane row of NetworkArrays, -1 for the centre lane
    lane_id: list
    section: list
    start: list
    end: list
    t_offset: list
    width: list
    colour: list
    length: list    # paint length (0: solid)
    space: list
    phase: list     # s where the first dash starts
    dots: list


def _line_rows(odr, roads=None) -> _Lines:
    """The mark lines of every road (of the ``roads`` indices only, when given)."""
    arrays = odr.arrays
    first_section = np.searchsorted(arrays.section_road, np.arange(len(odr.roads)), side="left")
    first_lane = np.searchsorted(arrays.lane_section, np.arange(len(arrays.section_s0) + 1), side="left")
    out = _Lines(*[[] for _ in range(13)])
    for road_index in (range(len(odr.roads)) if roads is None else np.asarray(roads).tolist()):
        road = odr.roads[road_index]
        section_index = int(first_section[road_index])
        for k, section in enumerate(road.lane_sections):
            end = road.section_end(k)
            rows = range(first_lane[section_index], first_lane[section_index + 1])
            row_of = {int(arrays.lane_id[row]): row for row in rows}
            for lane in section.lanes:
                if not lane.road_marks or end - section.s0 <= 0:
                    continue
                row = -1 if lane.id == 0 else row_of.get(lane.id)
                if row is None:
                    continue
                marks = sorted(lane.road_marks, key=lambda m: m.s_offset)
                for j, mark in enumerate(marks):
                    a = max(mark.s_offset, section.s0)
                    b = min(marks[j + 1].s_offset if j + 1 < len(marks) else end, end)
                    if b - a <= 1e-6:
                        continue
                    for line in _mark_lines(mark):
                        t_offset, width, colour, length, space, s_offset, dots = line
                        out.road.append(road_index)
                        out.row.append(row)
                        out.lane_id.append(lane.id)
                        out.section.append(section_index)
                        out.start.append(a)
                        out.end.append(b)
                        out.t_offset.append(t_offset)
                        out.width.append(width)
                        out.colour.append(colour)
                        out.length.append(length)
                        out.space.append(space)
                        out.phase.append(a + s_offset)
                        out.dots.append(dots)
            section_index += 1
    return out


def _mark_lines(mark):
    """(t_offset, width, colour, length, space, s_offset, dots) of each painted line of a road mark."""
    kind = (mark.type or "none").lower()
    width = mark.width if mark.width else (mark.type_width or DEFAULT_WIDTH.get(mark.weight or "", STANDARD_WIDTH))
    colour = colour_index(mark.color)
    if mark.lines:
        return [(line.t_offset, line.width if line.width else width, colour_index(line.color or mark.color),
                 line.length if line.space > 0 else 0.0, line.space, line.s_offset, False)
                for line in mark.lines if (line.width is None or line.width > 0)]
    if kind in NO_PAINT:
        return []
    if kind == "botts dots":
        return [(0.0, DOT_SIZE, colour, DOT_SIZE, DOT_SPACING - DOT_SIZE, 0.0, True)]
    parts = kind.split()
    if len(parts) == 1:
        offsets = [0.0]
    elif len(parts) == 2:
        offsets = [width, -width]  # centres one width apart from the border: a gap of one width
    else:
        return []
    lines = []
    for part, offset in zip(parts, offsets):
        if part == "solid":
            lines.append((offset, width, colour, 0.0, 0.0, 0.0, False))
        elif part == "broken":
            lines.append((offset, width, colour, BROKEN[0], BROKEN[1], 0.0, False))
    return lines


def _pieces(lines: _Lines, budget):
    """Expand dashed lines into one (line, a, b) piece per dash; solid lines are one piece."""
    start, end = np.array(lines.start), np.array(lines.end)
    length, space, phase = np.array(lines.length), np.array(lines.space), np.array(lines.phase)
    solid = length <= 0
    period = np.where(solid, 1.0, length + space)
    first = np.where(solid, 0.0, np.floor((start - phase) / period))
    last = np.where(solid, 0.0, np.floor((end - phase) / period))
    # a dash of 1e-9 m (or a phase far from the line) is a broken file, not a million dashes
    budget.check(np.array(lines.road), last - first + 1, "road-mark dashes")
    first, last = first.astype(np.int64), last.astype(np.int64)
    count = last - first + 1
    line = np.repeat(np.arange(len(start)), count)
    k = np.repeat(first, count) + np.arange(len(line)) - np.repeat(np.cumsum(count) - count, count)
    dash_a = phase[line] + k * period[line]
    a = np.where(solid[line], start[line], np.maximum(dash_a, start[line]))
    b = np.where(solid[line], end[line], np.minimum(dash_a + length[line], end[line]))
    keep = b - a > 1e-3
    return line[keep], a[keep], b[keep]


def road_marks(odr, eps: float = 0.05, samples: AdaptiveSamples | None = None, roads=None) -> RoadMarkMesh:
    """Every painted road mark of the map (kind "roadmark"), on the lane surface's adaptive samples; of the
    ``roads`` indices only when given (``samples`` must then cover their sections). Each road's marks depend
    on that road alone."""
    from tavf_mapkit.mesh.adaptive import adaptive_samples

    lines = _line_rows(odr, roads)
    if not lines.road:
        return RoadMarkMesh.empty()
    if samples is None:
        samples = adaptive_samples(odr, eps)
    line, a, b = _pieces(lines, odr.arrays.budget)
    dots = np.array(lines.dots, dtype=bool)[line]
    ribbons = _ribbons(odr, lines, line[~dots], a[~dots], b[~dots], samples)
    boxes = _dots(odr, lines, line[dots], a[dots], b[dots])
    parts = [m for m in (ribbons, boxes) if len(m.faces)]
    if not parts:
        return RoadMarkMesh.empty()
    base = LabelledMesh.concatenate(parts)
    marks = RoadMarkMesh(base.vertices, base.faces, base.road_index, base.lane_id, base.kind, base.uv,
                         np.concatenate([p.colour for p in parts]))
    return marks.select(proper_faces(marks.vertices, marks.faces))


def _positions(odr, lines: _Lines, line: np.ndarray, s: np.ndarray, t_extra: np.ndarray, lift: np.ndarray):
    """Points on the line's border at s, moved t_extra across and lifted above the lane surface."""
    row = np.array(lines.row)[line]
    road = np.array(lines.road)[line]
    point, e_t, e_h, lane_offset = reference_frames(odr, road, s)
    t = lane_offset.copy()
    height = np.zeros(len(s))
    side = row >= 0
    if np.any(side):
        _, t_outer = border_offsets(odr.arrays, row[side], s[side])
        t[side] = t_outer
        height[side] = odr.arrays.lane_height_outer.evaluate(row[side], s[side])
    t = t + np.array(lines.t_offset)[line] + t_extra
    return point + t[:, None] * e_t + (height + lift)[:, None] * e_h, t


def _ribbons(odr, lines: _Lines, line, a, b, samples: AdaptiveSamples) -> RoadMarkMesh:
    if not len(line):
        return RoadMarkMesh.empty()
    section = np.array(lines.section)[line]
    # the surface's own samples inside each piece, plus the piece's ends (an exact search by (section, s),
    # so the samples of other sections never matter)
    lo = search_pairs(samples.section, samples.s, section, a, "right")
    hi = search_pairs(samples.section, samples.s, section, b, "left")
    inner = np.maximum(hi - lo, 0)
    count = inner + 2
    piece = np.repeat(np.arange(len(line)), count)
    k = np.arange(len(piece)) - np.repeat(np.cumsum(count) - count, count)
    s = np.where(k == 0, a[piece], np.where(k == count[piece] - 1, b[piece],
                                            samples.s[np.minimum(lo[piece] + k - 1, len(samples.s) - 1)]))
    half = 0.5 * np.array(lines.width)[line][piece]
    lift = np.full(len(s), LIFT)
    left, t_left = _positions(odr, lines, line[piece], s, half, lift)
    right, t_right = _positions(odr, lines, line[piece], s, -half, lift)
    n = len(s)
    vertices = np.concatenate([right, left])
    uv = np.concatenate([np.column_stack([s, t_right]), np.column_stack([s, t_left])])
    j = np.flatnonzero(piece[1:] == piece[:-1])  # consecutive samples of one piece
    r0, r1, l0, l1 = j, j + 1, n + j, n + j + 1
    faces = np.concatenate([np.column_stack([r0, r1, l1]), np.column_stack([r0, l1, l0])]).astype(np.int64)
    face_line = np.tile(line[piece[j]], 2)
    # where a border folds over itself (a curve tighter than the lane's offset, or the seam at a kink) the
    # ribbon turns upside down: that paint lies under the rest of the ribbon, drop it
    _, _, e_h, _ = reference_frames(odr, np.array(lines.road)[face_line], np.tile(s[j], 2))
    up = np.einsum("ij,ij->i", face_cross(vertices, faces), e_h) > 0
    return _labelled(lines, vertices, faces[up], face_line[up], uv)


def _dots(odr, lines: _Lines, line, a, b) -> RoadMarkMesh:
    """Botts dots: a box per dot (top and four sides), DOT_HEIGHT high."""
    if not len(line):
        return RoadMarkMesh.empty()
    centre_s = 0.5 * (a + b)
    half = 0.5 * DOT_SIZE
    corners_s = np.repeat(centre_s, 4) + np.tile([-half, half, half, -half], len(line))
    corners_t = np.tile([-half, -half, half, half], len(line))
    line4 = np.repeat(line, 4)
    base, t = _positions(odr, lines, line4, corners_s, corners_t, np.full(len(line4), LIFT - DOT_HEIGHT / 2))
    top, _ = _positions(odr, lines, line4, corners_s, corners_t, np.full(len(line4), LIFT + DOT_HEIGHT / 2))
    n = len(base)
    vertices = np.concatenate([base, top])
    uv = np.tile(np.column_stack([corners_s, t]), (2, 1))
    o = 4 * np.arange(len(line))[:, None]
    # corners 0..3 counter-clockwise seen from above; top = n + corner
    template = np.array([[4, 5, 6], [4, 6, 7],                       # top
                         [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],  # sides
                         [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    local = np.where(template >= 4, template - 4 + n, template)
    faces = (local[None, :, :] + o[:, :, None]).reshape(-1, 3).astype(np.int64)
    return _labelled(lines, vertices, faces, np.repeat(line, len(template)), uv)


def _labelled(lines: _Lines, vertices, faces, face_line, uv) -> RoadMarkMesh:
    return RoadMarkMesh(vertices, faces, np.array(lines.road, dtype=np.int32)[face_line],
                        np.array(lines.lane_id, dtype=np.int32)[face_line],
                        np.full(len(faces), KIND_CODE["roadmark"], dtype=np.int16), uv,
                        np.array(lines.colour, dtype=np.int8)[face_line])
