"""Lane keys and the driving direction of a lane."""

from __future__ import annotations

from typing import NamedTuple


class LaneKey(NamedTuple):
    """One lane of one lane section: ``(road_index, section_index, lane_id)`` (indices into ``odr.roads``)."""

    road_index: int
    section_index: int
    lane_id: int


def drives_with_s(road, lane) -> bool:
    """True if traffic in the lane moves towards increasing s.

    Right-hand traffic (the default): right lanes (id < 0) run with s, left lanes against it; ``rule="LHT"``
    mirrors that. An OpenDRIVE 1.8 ``direction="reversed"`` lane runs the other way.
    """
    forward = lane.id < 0 if road.rule != "LHT" else lane.id > 0
    if lane.attrib.get("direction") == "reversed":
        forward = not forward
    return forward


def lane_toward_plus_t(lane_id: int) -> int:
    """The id of the neighbouring lane on the +t side (lane 0 carries no traffic and is skipped)."""
    return 1 if lane_id == -1 else lane_id + 1


def lane_toward_minus_t(lane_id: int) -> int:
    return -1 if lane_id == 1 else lane_id - 1
