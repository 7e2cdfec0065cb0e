"""Lane-change permission from the road mark between two neighbouring lanes of one side.

The mark between lanes k and k+1 of a side is the outer road mark of the inner lane. Its ``laneChange``
attribute decides when present ("increase": towards higher lane ids, "decrease", "both", "none"); else its
type: solid lines forbid crossing, "solid broken" allows it from the broken side only (the side of the
second line, i.e. from the outer lane), "broken solid" from the inner lane; no mark allows it.
"""

from __future__ import annotations

_FORBIDDEN = {"solid", "solid solid", "curb", "grass", "edge"}


def mark_at(lane, s: float):
    """The road mark of ``lane`` in force at road s (the last one starting at or before it), or None."""
    mark = None
    for candidate in sorted(lane.road_marks, key=lambda m: m.s_offset):
        if candidate.s_offset <= s + 1e-9:
            mark = candidate
    return mark


def lane_change_allowed(section, from_id: int, to_id: int, at: float = 0.0) -> bool:
    """May a vehicle cross from lane ``from_id`` into the neighbouring lane ``to_id`` of the same side?

    ``at`` is the road s where the mark is read (the graph uses the middle of the section).
    """
    inner_id = from_id if abs(from_id) < abs(to_id) else to_id
    inner = section.by_id.get(inner_id)
    if inner is None:
        return True
    mark = mark_at(inner, at)
    if mark is None:
        return True
    if mark.lane_change is not None:
        rule = mark.lane_change
        if rule == "both":
            return True
        if rule == "none":
            return False
        increasing = to_id > from_id
        return (rule == "increase") == increasing
    kind = (mark.type or "none").lower()
    if kind in _FORBIDDEN:
        return False
    from_outer = abs(from_id) > abs(to_id)
    if kind == "solid broken":
        return from_outer
    if kind == "broken solid":
        return not from_outer
    return True

