"""OpenDRIVE signals as solids: a pole and one plate (sign) or housing (traffic light) per signal.

Signals at the same place on a road share one pole and become one solid (their union). A signal placed on a
drivable lane -- netconvert puts every traffic light at the centre of its lane with zOffset 5 m -- hangs there
without a pole (a gantry/overhead light), so the collision world does not block the lane.

The plate faces the traffic it is valid for: orientation "+" faces vehicles driving in +s (its face looks
towards -s), "-" the opposite, "none" both; hOffset turns it further. Plates stand in front of the pole.
"""

from __future__ import annotations

import math

import manifold3d
import numpy as np

from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS, LANE_TYPE_KIND
from tavf_mapkit.mesh.solid_kit import Solid, SolidError, circle_segments, rotated, to_solid

POLE_RADIUS = 0.05        # m
SIGN_DEPTH = 0.03         # m: a static sign plate
LIGHT_DEPTH = 0.3         # m: the housing of a dynamic signal (traffic light)
DEFAULT_SIZE = 0.6        # m: width/height of a signal that states neither


def on_drivable_lane(lane_type: str | None) -> bool:
    """Whether vehicles use a lane of this type (the road surface's drivable kinds, trams and rails too)."""
    if lane_type is None:
        return False
    kind = LANE_TYPE_KIND.get(lane_type.lower(), "other")
    return kind in DRIVABLE_KINDS or lane_type.lower() in ("tram", "rail")


def lane_type_at(road, s: float, t: float) -> str | None:
    """Type of the lane that contains road coordinates (s, t), None when (s, t) is off the road."""
    s = float(np.clip(s, 0.0, road.length))
    index = int(road.section_index(s))
    section = road.lane_sections[index]
    borders = {lane: float(values[0]) for lane, values in road.lane_borders(index, s).items()}
    inner = borders[0]
    lanes = section.left if t >= inner else section.right
    for lane in lanes:
        outer = borders[lane.id]
        if min(inner, outer) - 1e-6 <= t <= max(inner, outer) + 1e-6:
            return lane.type
        inner = outer
    return None


def signal_solids(odr, eps: float = 0.05, roads=None) -> tuple[list[Solid], list[str]]:
    """One solid per signal position (pole + plates), and a line per position that has none (why); of the
    ``roads`` indices only, when given."""
    from tavf_mapkit.opendrive.surface import surface_points

    groups = []  # (road index, s, t, signals), positions of all roads evaluated in one pass
    for road_index in (range(len(odr.roads)) if roads is None else np.asarray(roads).tolist()):
        road = odr.roads[road_index]
        by_place: dict[tuple[float, float], list] = {}
        for signal in road.signals:
            by_place.setdefault((round(signal.s, 2), round(signal.t, 2)), []).append(signal)
        groups.extend((road_index, float(np.clip(s, 0.0, road.length)), t, signals)
                      for (s, t), signals in sorted(by_place.items()))
    if not groups:
        return [], []
    road_rows = np.array([g[0] for g in groups], dtype=np.int64)
    s = np.array([g[1] for g in groups])
    t = np.array([g[2] for g in groups])
    x, y, z, heading, slope, superelevation, _ = odr.arrays.reference(road_rows, s)
    bases = surface_points(x, y, z, heading, slope, superelevation, t)
    solids, skipped = [], []
    for k, (road_index, s_k, t_k, signals) in enumerate(groups):
        road = odr.roads[road_index]
        where = f"road {road.id} signal {','.join(sig.id for sig in signals)}"
        has_pole = not on_drivable_lane(lane_type_at(road, s_k, t_k))
        try:
            solids.append(_signal_group(bases[k], float(heading[k]), has_pole, road_index, signals, eps, where))
        except SolidError as error:
            skipped.append(f"{where}: {error}")
    return solids, skipped


def _signal_group(base, heading, has_pole, road_index, signals, eps, where) -> Solid:
    parts, seen = [], set()
    top = 0.0
    for signal in signals:
        height = signal.height if signal.height and signal.height > 0 else (signal.width or DEFAULT_SIZE)
        width = signal.width if signal.width and signal.width > 0 else height
        depth = LIGHT_DEPTH if signal.dynamic else SIGN_DEPTH
        key = (round(signal.z_offset, 3), round(width, 3), round(height, 3), depth, signal.orientation,
               round(signal.h_offset, 4), round(signal.pitch, 4), round(signal.roll, 4))
        if key in seen:
            continue
        seen.add(key)
        top = max(top, signal.z_offset + height)
        front = POLE_RADIUS if has_pole else -depth / 2
        plate = manifold3d.Manifold.cube([depth, width, height]).translate([front, -width / 2, signal.z_offset])
        facing = {"+": math.pi, "-": 0.0}.get(signal.orientation)
        if facing is None:  # valid both ways: a plate on each side
            plate = plate + plate.rotate([0.0, 0.0, 180.0])
            facing = 0.0
        parts.append(rotated(plate, heading + facing + signal.h_offset, signal.pitch, signal.roll))
    if has_pole and top > 0.05:
        parts.append(manifold3d.Manifold.cylinder(top, POLE_RADIUS,
                                                  circular_segments=circle_segments(POLE_RADIUS, eps)))
    if not parts:
        raise SolidError("no plate and no pole")
    union = manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add)
    return to_solid(union, "signal", where, base, road_index=road_index)
