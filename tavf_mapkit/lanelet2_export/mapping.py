"""What OpenDRIVE lanes and road marks become in Lanelet2: lanelet subtypes and line types.

Lane types (compared case-insensitively) map to the lanelet subtypes of Lanelet2's traffic rules; lanes whose
type has no lanelet counterpart (shoulder, border, parking, median, curb, none, restricted, tram, ...) are
left out, their borders still bound the lanelets beside them. Road marks map to the line types of Lanelet2's
LinestringTagging: the mark drawn on a border is the outer mark of the lane inside it (lane 0's on the centre
line), read at the middle of the lane section, as the lane graph reads it for lane changes.
"""

from __future__ import annotations

#: lane types vehicles drive on (lanelet subtype road, or highway on motorways), spelled as OpenDRIVE writes
#: them
VEHICLE_LANE_TYPE_NAMES = (
    "driving",
    "entry",
    "exit",
    "onRamp",
    "offRamp",
    "connectingRamp",
    "mwyEntry",
    "mwyExit",
    "slipLane",
    "bidirectional",
)
VEHICLE_LANE_TYPES = frozenset(name.lower() for name in VEHICLE_LANE_TYPE_NAMES)

_OTHER_LANE_TAGS = {
    "biking": {"subtype": "bicycle_lane", "one_way": "yes"},
    "sidewalk": {"subtype": "walkway"},
    "walking": {"subtype": "walkway"},
    "bus": {"subtype": "bus_lane", "one_way": "yes"},
    # Lanelet2's participant override: passable for taxis (and buses) only, not for every vehicle
    "taxi": {"subtype": "road", "one_way": "yes", "participant:vehicle:taxi": "yes"},
    "hov": {
        "subtype": "road",
        "one_way": "yes",
        "participant:vehicle:taxi": "yes",
        "participant:vehicle:bus": "yes",
    },
    "stop": {"subtype": "emergency_lane", "one_way": "yes"},  # OpenDRIVE's hard shoulder for emergency stops
}

#: a height step across a border larger than this is a curb (m; the mesher's MIN_RAISE)
CURB_RAISE = 1e-4
#: curbs lower than this are Lanelet2's curbstone low (m)
LOW_CURB = 0.1

#: road types outside towns (Lanelet2's location=nonurban; its default speed limits depend on it)
_NONURBAN_ROAD_TYPES = frozenset({"rural", "motorway"})


def lanelet_tags(lane_type: str, road_type: str | None) -> dict[str, str] | None:
    """Tags of a lane's lanelet (type, subtype, location, one_way), None for lanes that get no lanelet."""
    kind = (lane_type or "").lower()
    location = "nonurban" if (road_type or "").lower() in _NONURBAN_ROAD_TYPES else "urban"
    if kind in VEHICLE_LANE_TYPES:
        subtype = "highway" if (road_type or "").lower() == "motorway" else "road"
        return {
            "type": "lanelet",
            "subtype": subtype,
            "location": location,
            "one_way": "no" if kind == "bidirectional" else "yes",
        }
    tags = _OTHER_LANE_TAGS.get(kind)
    if tags is None:
        return None
    return {"type": "lanelet", **tags, "location": location}


def is_vehicle_lane(lane_type: str) -> bool:
    return (lane_type or "").lower() in VEHICLE_LANE_TYPES


# -- road marks
# -----------------------------------------------------------------------------------------------

_SINGLE = {
    "solid": "solid",
    "broken": "dashed",
    "broken broken": "dashed",
    "botts dots": "dashed",
    "solid solid": "solid_solid",
}
_BORDER = {"grass": "road_border", "edge": "road_border"}
#: OpenDRIVE names two-line marks from the inner line to the outer one
_TWO_LINES = {"solid broken": ("solid", "dashed"), "broken solid": ("dashed", "solid")}


def line_tags(mark, inner_on_left: bool, curb_raise: float, curb_beside: bool = False) -> dict[str, str]:
    """Tags of a border way from the road mark on it (``None``: no mark) and the height step across it.

    ``inner_on_left``: the way runs with s, so the lane inside the border lies on its left for right-side
    lanes and on its right for left-side lanes (two-line marks put their first line on the inner side).
    ``curb_raise``: the largest height step between the lanes on both sides (m); a step is a curbstone, and so
    is a border beside an OpenDRIVE 1.8 lane of type curb (``curb_beside``).
    """
    kind = ((mark.type if mark is not None else None) or "none").lower()
    if curb_beside and curb_raise <= CURB_RAISE:
        return {"type": "curbstone", "subtype": "high"}
    if kind == "curb" or curb_raise > CURB_RAISE:
        return {"type": "curbstone", "subtype": "low" if CURB_RAISE < curb_raise < LOW_CURB else "high"}
    if kind in _BORDER:
        return {"type": _BORDER[kind]}
    if kind in _SINGLE:
        tags = {"type": _thickness(mark), "subtype": _SINGLE[kind]}
    elif kind in _TWO_LINES:
        inner, outer = _TWO_LINES[kind]
        left, right = (inner, outer) if inner_on_left else (outer, inner)
        tags = {"type": _thickness(mark), "subtype": f"{left}_{right}"}
    else:  # none, custom, unknown: nothing a driver sees
        return {"type": "virtual"}
    colour = (mark.color or "standard").lower()
    if colour not in ("standard", "white"):
        tags["color"] = colour
    return tags


def _thickness(mark) -> str:
    return "line_thick" if (mark.weight or "").lower() == "bold" else "line_thin"


def implied_lane_change(tags: dict[str, str]) -> tuple[bool, bool]:
    """(to the left, to the right) of the way's direction that Lanelet2's vehicle rules read from line tags
    (GenericTrafficRules: dashed both ways, solid_dashed to the left, dashed_solid to the right, else none).
    """
    if tags.get("type") not in ("line_thin", "line_thick"):
        return False, False
    subtype = tags.get("subtype")
    return subtype in ("dashed", "solid_dashed"), subtype in ("dashed", "dashed_solid")


def lane_change_tags(wanted: tuple[bool, bool], tags: dict[str, str]) -> dict[str, str]:
    """Explicit lane_change tags where the line type alone would tell Lanelet2 something else than the map.

    Lanelet2 reads ``lane_change:left=no`` as "no change at all" even when ``lane_change:right=yes``, so a
    one-sided permission is written as the one ``yes`` tag alone.
    """
    if implied_lane_change(tags) == wanted:
        return {}
    left, right = wanted
    if left and right:
        return {"lane_change": "yes"}
    if not left and not right:
        return {"lane_change": "no"}
    return {"lane_change:left": "yes"} if left else {"lane_change:right": "yes"}
