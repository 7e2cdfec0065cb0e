"""OpenDRIVE road objects as solids: boxes, cylinders, outlines (cornerLocal / cornerRoad, closed or open)
and repeats (instances every ``distance`` metres, or one continuous sweep when ``distance`` is 0).

Conventions (ASAM OpenDRIVE 1.7, section 13):
- The object's origin is the road surface at (s, t) raised by ``zOffset``; its heading is the road's heading
  at s plus ``hdg``; a box is centred on the origin in plan and stands on it; a cylinder likewise.
- An object with a repeat is a template: the repeat's instances replace it.
- An object without any size (it names an external 3D model) has no solid; one with a height but no
  footprint becomes a post of ``DEFAULT_POST`` x ``DEFAULT_POST`` metres; a continuous repeat without a
  width becomes a wall ``DEFAULT_POST`` thick. Zero-height objects and outlines are surface markings: no solid.
"""

from __future__ import annotations

import math

import manifold3d
import numpy as np

from tavf_mapkit.mesh.solid_kit import (
    Solid,
    SolidError,
    circle_segments,
    extrude_down,
    manifold_from_mesh,
    rotated,
    strip_faces,
    to_solid,
)
from tavf_mapkit.opendrive.objects import ObjectRepeat, Outline, RoadObject

DEFAULT_POST = 0.1     # m: footprint of objects that only state a height, thickness of width-less walls
SWEEP_STEP = 0.5       # m of s between cross-sections of a continuous repeat
OPEN_OUTLINE_WIDTH = 0.1  # m: an open outline is a wall of this thickness along its corners
MAX_INSTANCES = 10_000    # per repeat: more is a broken file, not a fence (refused, not ground through)
MAX_SWEEP_SAMPLES = 100_000


def object_solids(odr, eps: float = 0.05, roads=None) -> tuple[list[Solid], list[str]]:
    """Solids of every road object (of the ``roads`` indices, when given), and one line per object that has
    none (why)."""
    solids, skipped = [], []
    for road_index in (range(len(odr.roads)) if roads is None else np.asarray(roads).tolist()):
        road = odr.roads[road_index]
        for obj in road.objects:
            where = f"road {road.id} object {obj.id}"
            try:
                built = _object(road, road_index, obj, eps, where)
            except SolidError as error:
                skipped.append(f"{where}: {error}")
                continue
            if not built:
                skipped.append(f"{where}: no size (an external model) or zero height")
            solids.extend(built)
    return solids, skipped


def _object(road, road_index: int, obj: RoadObject, eps: float, where: str) -> list[Solid]:
    out: list[Solid] = []
    if obj.repeats:
        for k, repeat in enumerate(obj.repeats):
            if repeat.distance < 0 or repeat.length < 0:
                raise SolidError(f"repeat {k} has a negative distance or length")
            if repeat.distance > 0:
                for i, params in enumerate(_repeat_instances(road, obj, repeat)):
                    out.extend(_placed(road, road_index, obj, params, eps, f"{where} repeat {k} #{i}",
                                       road_outlines=False))
            else:
                sweep = _continuous(road, road_index, obj, repeat, f"{where} repeat {k}")
                if sweep is not None:
                    out.append(sweep)
        # cornerRoad outlines are absolute: they are not repeated
        out.extend(_road_outlines(road, road_index, obj, where))
        return out
    params = {"s": obj.s, "t": obj.t, "z_offset": obj.z_offset, "length": obj.length, "width": obj.width,
              "height": obj.height, "radius": obj.radius}
    return _placed(road, road_index, obj, params, eps, where, road_outlines=True)


def _frame(road, s: float, t: float, z_offset: float, hdg: float):
    s = float(np.clip(s, 0.0, road.length))
    base = road.surface_point(s, t)[0] + np.array([0.0, 0.0, z_offset])
    heading = float(road.reference_point(s)[3][0])
    return base, heading + hdg


def _placed(road, road_index, obj, params, eps, where, road_outlines: bool) -> list[Solid]:
    base, yaw = _frame(road, params["s"], params["t"], params["z_offset"], obj.hdg)
    out = []
    local = [o for o in obj.outlines if o.corners and o.corners[0].kind == "cornerLocal"]
    if local:
        for k, outline in enumerate(local):
            solid = _local_outline(outline, base, yaw, road_index, f"{where} outline {k}")
            if solid is not None:
                out.append(solid)
    elif not obj.outlines:
        shape = _primitive(params, eps)
        if shape is not None:
            shape = rotated(shape, yaw, obj.pitch, obj.roll)
            out.append(to_solid(shape, "object", where, base, road_index=road_index))
    if road_outlines:
        out.extend(_road_outlines(road, road_index, obj, where))
    return out


def _primitive(params, eps) -> manifold3d.Manifold | None:
    height = params["height"]
    if height is None or height <= 0:
        return None
    radius, length, width = params["radius"], params["length"], params["width"]
    if radius is not None and radius > 0:
        return manifold3d.Manifold.cylinder(height, radius, circular_segments=circle_segments(radius, eps))
    length = length if length and length > 0 else None
    width = width if width and width > 0 else None
    if length is None and width is None:
        length = width = DEFAULT_POST
    length, width = length or width, width or length
    return manifold3d.Manifold.cube([length, width, height], center=False).translate([-length / 2, -width / 2, 0])


def _interpolate(start, end, fallback, fraction):
    if start is None:
        return fallback
    if end is None:
        return start
    return start + (end - start) * fraction


def _repeat_instances(road, obj: RoadObject, repeat: ObjectRepeat):
    length = max(0.0, min(repeat.length, road.length - repeat.s))
    count = math.floor(length / repeat.distance + 1e-9) + 1
    if count > MAX_INSTANCES:
        raise SolidError(f"repeat would place {count} instances (distance {repeat.distance} m over {length} m; "
                         f"limit {MAX_INSTANCES})")
    for i in range(count):
        fraction = i * repeat.distance / length if length > 0 else 0.0
        yield {
            "s": repeat.s + i * repeat.distance,
            "t": repeat.t_start + (repeat.t_end - repeat.t_start) * fraction,
            "z_offset": repeat.z_offset_start + (repeat.z_offset_end - repeat.z_offset_start) * fraction,
            "length": _interpolate(repeat.length_start, repeat.length_end, obj.length, fraction),
            "width": _interpolate(repeat.width_start, repeat.width_end, obj.width, fraction),
            "height": _interpolate(repeat.height_start, repeat.height_end, obj.height, fraction),
            "radius": _interpolate(repeat.radius_start, repeat.radius_end, obj.radius, fraction),
        }


def _continuous(road, road_index, obj: RoadObject, repeat: ObjectRepeat, where: str) -> Solid | None:
    """A wall along the road: cross-sections every SWEEP_STEP of s, t/width/height/zOffset interpolated."""
    s0 = float(np.clip(repeat.s, 0.0, road.length))
    s1 = float(np.clip(repeat.s + repeat.length, 0.0, road.length))
    if s1 - s0 <= 1e-6:
        return None
    s = np.linspace(s0, s1, max(2, min(MAX_SWEEP_SAMPLES, math.ceil((s1 - s0) / SWEEP_STEP) + 1)))
    fraction = (s - repeat.s) / repeat.length if repeat.length > 0 else np.zeros_like(s)

    def along(start, end, fallback):
        if start is None:
            return np.full_like(s, np.nan if fallback is None else fallback)
        return start + ((start if end is None else end) - start) * fraction

    height = along(repeat.height_start, repeat.height_end, obj.height)
    if np.isnan(height).any() or np.max(height) <= 0:
        return None
    width = along(repeat.width_start, repeat.width_end, obj.width)
    radius = along(repeat.radius_start, repeat.radius_end, obj.radius)
    width = np.where(np.isnan(width), 2.0 * radius, width)
    width = np.where(np.isnan(width) | (width <= 0), DEFAULT_POST, width)
    height = np.maximum(height, 1e-3)
    t = repeat.t_start + (repeat.t_end - repeat.t_start) * fraction
    z = repeat.z_offset_start + (repeat.z_offset_end - repeat.z_offset_start) * fraction
    right = road.surface_point(s, t - width / 2)
    left = road.surface_point(s, t + width / 2)
    top = np.concatenate([right, left])
    top[:, 2] += np.tile(z + height, 2)
    anchor = top.mean(axis=0)
    vertices, faces = extrude_down(top - anchor, strip_faces(len(s)), np.tile(height, 2))
    return to_solid(manifold_from_mesh(vertices, faces), "object", where, anchor, road_index=road_index)


def _extruded_outline(xy, bottom, top, anchor, road_index, where, closed: bool) -> Solid | None:
    """A prism over an outline: its polygon (or, when open, a thin wall along its corners), with bottom and top
    heights taken from the nearest corner."""
    if np.max(top - bottom) <= 1e-3:
        return None
    top = np.maximum(top, bottom + 1e-3)
    local = xy - anchor[:2]
    if closed:
        section = manifold3d.CrossSection([local], manifold3d.FillRule.EvenOdd)
    else:
        import shapely

        wall = shapely.LineString(local).buffer(OPEN_OUTLINE_WIDTH / 2, cap_style="flat", join_style="mitre")
        section = manifold3d.CrossSection([np.asarray(wall.exterior.coords)[:-1]], manifold3d.FillRule.EvenOdd)
    if section.is_empty() or section.area() <= 1e-6:
        raise SolidError("outline encloses no area")
    prism = manifold3d.Manifold.extrude(section, 1.0)
    z0, z1 = bottom - anchor[2], top - anchor[2]

    def lift(points):
        points = np.array(points, dtype=np.float64)
        nearest = np.argmin(((points[:, None, :2] - local[None, :, :]) ** 2).sum(axis=2), axis=1)
        points[:, 2] = z0[nearest] + points[:, 2] * (z1[nearest] - z0[nearest])
        return points

    return to_solid(prism.warp_batch(lift), "object", where, anchor, road_index=road_index)


def _local_outline(outline: Outline, base, yaw, road_index, where) -> Solid | None:
    corners = outline.corners
    uv = np.array([[c.a, c.b] for c in corners])
    c, s = math.cos(yaw), math.sin(yaw)
    xy = base[:2] + uv @ np.array([[c, s], [-s, c]])
    bottom = base[2] + np.array([c.z for c in corners])
    top = bottom + np.array([c.height for c in corners])
    return _extruded_outline(xy, bottom, top, base, road_index, where, outline.closed)


def _road_outlines(road, road_index, obj: RoadObject, where: str) -> list[Solid]:
    out = []
    for k, outline in enumerate(obj.outlines):
        corners = outline.corners
        if not corners or corners[0].kind != "cornerRoad":
            continue
        s = np.clip([c.a for c in corners], 0.0, road.length)
        points = road.surface_point(s, np.array([c.b for c in corners]))
        bottom = points[:, 2] + np.array([c.z for c in corners])
        top = bottom + np.array([c.height for c in corners])
        anchor = points.mean(axis=0)
        solid = _extruded_outline(points[:, :2], bottom, top, anchor, road_index, f"{where} outline {k}",
                                  outline.closed)
        if solid is not None:
            out.append(solid)
    return out
