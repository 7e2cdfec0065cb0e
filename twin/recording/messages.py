"""Turn the twin's values (a step's ``Frame``, a GNSS fix, UDM answers) into the recording's JSON messages."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import fields
from typing import Any

import numpy as np

from twin.recording.schemas import EGO_FRAME, GNSS_FRAME, MAP_FRAME
from twin.session.hooks import Frame
from twin.udm.model import Layer, UdmObject

FRAME_FIELDS = tuple(f.name for f in fields(Frame) if f.name != "gnss")
# Drawn size of an object without an extent (a sign post), metres.
DEFAULT_SIZE = (0.5, 0.5, 2.5)
LAYER_COLORS = {  # RGBA: static grey, transient static blue, transient dynamic orange, highly dynamic red
    int(Layer.STATIC_MAP): (0.6, 0.6, 0.6, 0.9),
    int(Layer.TRANSIENT_STATIC): (0.2, 0.4, 1.0, 0.9),
    int(Layer.TRANSIENT_DYNAMIC): (1.0, 0.6, 0.1, 0.9),
    int(Layer.HIGHLY_DYNAMIC): (1.0, 0.1, 0.1, 0.9),
}


def stamp(log_time_ns: int) -> dict[str, int]:
    sec, nsec = divmod(log_time_ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def quaternion(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> dict[str, float]:
    """Z-Y-X (yaw, pitch, roll) Euler angles in radians as a unit quaternion."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    return {"x": sr * cp * cy - cr * sp * sy, "y": cr * sp * cy + sr * cp * sy,
            "z": cr * cp * sy - sr * sp * cy, "w": cr * cp * cy + sr * sp * sy}


def ego_state(frame: Frame) -> dict[str, Any]:
    """Every field of the frame, exactly; the GNSS fix (if any) nested under ``gnss``."""
    state = {name: getattr(frame, name) for name in FRAME_FIELDS}
    if frame.gnss is not None:
        state["gnss"] = {name: getattr(frame.gnss, name) for name in frame.gnss.__slots__}
    return state


def ego_pose(frame: Frame, log_time_ns: int) -> dict[str, Any]:
    return {"timestamp": stamp(log_time_ns), "frame_id": MAP_FRAME,
            "pose": {"position": {"x": frame.x, "y": frame.y, "z": frame.z},
                     "orientation": quaternion(frame.yaw, frame.pitch, frame.roll)}}


def ego_transform(frame: Frame, log_time_ns: int) -> dict[str, Any]:
    return {"timestamp": stamp(log_time_ns), "parent_frame_id": MAP_FRAME, "child_frame_id": EGO_FRAME,
            "translation": {"x": frame.x, "y": frame.y, "z": frame.z},
            "rotation": quaternion(frame.yaw, frame.pitch, frame.roll)}


def location_fix(fix: Any, log_time_ns: int) -> dict[str, Any]:
    """A ``foxglove.LocationFix`` from a ``GnssFix`` (sigma per axis on the covariance diagonal, ENU)."""
    variance = float(fix.sigma_m) ** 2
    return {"timestamp": stamp(log_time_ns), "frame_id": GNSS_FRAME,
            "latitude": fix.lat, "longitude": fix.lon, "altitude": fix.alt,
            "position_covariance": [variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance],
            "position_covariance_type": 2}


def udm_scene(objects: Sequence[UdmObject], georeference: Any, ground_z: float,
              log_time_ns: int) -> dict[str, Any]:
    """A ``foxglove.SceneUpdate`` that replaces the whole UDM scene with these objects (drawn in ``map``)."""
    time = stamp(log_time_ns)
    deletions = [{"timestamp": time, "type": 1, "id": ""}]  # ALL: the scene shows the latest answer only
    if not objects or georeference is None:
        return {"deletions": deletions, "entities": []}
    x, y = georeference.wgs84_to_local(np.array([o.lon for o in objects]), np.array([o.lat for o in objects]))
    entities = []
    for index, obj in enumerate(objects):
        extent = obj.extent
        size = DEFAULT_SIZE if extent is None else (extent.length or DEFAULT_SIZE[0],
                                                    extent.width or DEFAULT_SIZE[1],
                                                    extent.height or DEFAULT_SIZE[2])
        # Compass heading (clockwise from north) -> yaw in the local frame (counter-clockwise from east);
        # the local frame's small rotation against true north is below what a drawn sign shows.
        yaw = math.radians(90.0 - obj.heading) if obj.heading is not None else 0.0
        z = ground_z + size[2] / 2
        pose = {"position": {"x": float(x[index]), "y": float(y[index]), "z": z}, "orientation": quaternion(yaw)}
        r, g, b, a = LAYER_COLORS.get(obj.layer, LAYER_COLORS[int(Layer.STATIC_MAP)])
        label_pose = {"position": {"x": float(x[index]), "y": float(y[index]), "z": ground_z + size[2] + 0.5},
                      "orientation": quaternion(0.0)}
        entities.append({
            "timestamp": time, "frame_id": MAP_FRAME, "id": obj.id, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [{"key": "layer", "value": str(obj.layer)}, {"key": "type", "value": obj.type},
                         {"key": "class", "value": obj.object_class}, {"key": "source", "value": obj.source}],
            "cubes": [{"pose": pose, "size": {"x": size[0], "y": size[1], "z": size[2]},
                       "color": {"r": r, "g": g, "b": b, "a": a}}],
            "texts": [{"pose": label_pose, "billboard": True, "font_size": 12.0, "scale_invariant": True,
                       "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
                       "text": f"{obj.type} {obj.object_class}".strip()}],
        })
    return {"deletions": deletions, "entities": entities}


def udm_geojson(objects: Sequence[UdmObject]) -> dict[str, Any]:
    """A ``foxglove.GeoJSON`` of the answer, for Foxglove's Map panel."""
    collection = {"type": "FeatureCollection", "features": [obj.to_feature() for obj in objects]}
    return {"geojson": json.dumps(collection, separators=(",", ":"))}
