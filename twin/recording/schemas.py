"""The channels of a session recording: topic names, schema names and their JSON Schemas.

Foxglove recognises a channel by its schema *name* (``foxglove.LocationFix`` ...) and decodes JSON messages
with the JSON Schema given; the schemas below are the subsets of Foxglove's published ones that we fill, so
Foxglove's Map and 3D panels open the file as is. ``twin.*`` schemas are our own plain JSON channels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

# Frames of the 3D scene: "map" is the OpenDRIVE local frame of the build, "base_link" the ego body.
MAP_FRAME = "map"
EGO_FRAME = "base_link"
GNSS_FRAME = "gnss"

_NUMBER: dict[str, Any] = {"type": "number"}
_STRING: dict[str, Any] = {"type": "string"}
_INTEGER: dict[str, Any] = {"type": "integer"}
_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}
_DURATION = {"type": "object", "title": "duration", "properties": {"sec": _INTEGER, "nsec": _INTEGER}}
_VECTOR3 = {"title": "foxglove.Vector3", "type": "object",
            "properties": {"x": _NUMBER, "y": _NUMBER, "z": _NUMBER}, "required": ["x", "y", "z"]}
_QUATERNION = {"title": "foxglove.Quaternion", "type": "object",
               "properties": {"x": _NUMBER, "y": _NUMBER, "z": _NUMBER, "w": _NUMBER},
               "required": ["x", "y", "z", "w"]}
_POSE = {"title": "foxglove.Pose", "type": "object",
         "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
         "required": ["position", "orientation"]}
_COLOR = {"title": "foxglove.Color", "type": "object",
          "properties": {"r": _NUMBER, "g": _NUMBER, "b": _NUMBER, "a": _NUMBER},
          "required": ["r", "g", "b", "a"]}
_KEY_VALUE = {"title": "foxglove.KeyValuePair", "type": "object",
              "properties": {"key": _STRING, "value": _STRING}, "required": ["key", "value"]}

LOCATION_FIX = {
    "title": "foxglove.LocationFix",
    "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "type": "object",
    "properties": {
        "timestamp": _TIME, "frame_id": _STRING, "latitude": _NUMBER, "longitude": _NUMBER,
        "altitude": _NUMBER,
        "position_covariance": {"type": "array", "items": _NUMBER, "minItems": 9, "maxItems": 9},
        "position_covariance_type": {"title": "foxglove.PositionCovarianceType", "type": "integer",
                                     "enum": [0, 1, 2, 3]},
        "heading": _NUMBER,
    },
    "required": ["timestamp", "frame_id", "latitude", "longitude", "altitude", "position_covariance",
                 "position_covariance_type"],
}

POSE_IN_FRAME = {
    "title": "foxglove.PoseInFrame",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object",
    "properties": {"timestamp": _TIME, "frame_id": _STRING, "pose": _POSE},
    "required": ["timestamp", "frame_id", "pose"],
}

FRAME_TRANSFORM = {
    "title": "foxglove.FrameTransform",
    "description": "A transform between two reference frames in 3D space",
    "type": "object",
    "properties": {"timestamp": _TIME, "parent_frame_id": _STRING, "child_frame_id": _STRING,
                   "translation": _VECTOR3, "rotation": _QUATERNION},
    "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
}

_CUBE = {"title": "foxglove.CubePrimitive", "type": "object",
         "properties": {"pose": _POSE, "size": _VECTOR3, "color": _COLOR},
         "required": ["pose", "size", "color"]}
_TEXT = {"title": "foxglove.TextPrimitive", "type": "object",
         "properties": {"pose": _POSE, "billboard": {"type": "boolean"}, "font_size": _NUMBER,
                        "scale_invariant": {"type": "boolean"}, "color": _COLOR, "text": _STRING},
         "required": ["pose", "billboard", "font_size", "scale_invariant", "color", "text"]}
_ENTITY = {
    "title": "foxglove.SceneEntity", "type": "object",
    "properties": {"timestamp": _TIME, "frame_id": _STRING, "id": _STRING, "lifetime": _DURATION,
                   "frame_locked": {"type": "boolean"}, "metadata": {"type": "array", "items": _KEY_VALUE},
                   "cubes": {"type": "array", "items": _CUBE}, "texts": {"type": "array", "items": _TEXT}},
    "required": ["timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata"],
}
_DELETION = {"title": "foxglove.SceneEntityDeletion", "type": "object",
             "properties": {"timestamp": _TIME, "type": {"type": "integer", "enum": [0, 1]}, "id": _STRING},
             "required": ["timestamp", "type", "id"]}
SCENE_UPDATE = {
    "title": "foxglove.SceneUpdate",
    "description": "An update to the entities displayed in a 3D scene",
    "type": "object",
    "properties": {"deletions": {"type": "array", "items": _DELETION},
                   "entities": {"type": "array", "items": _ENTITY}},
    "required": ["deletions", "entities"],
}

GEOJSON = {
    "title": "foxglove.GeoJSON",
    "description": "GeoJSON data for annotating maps",
    "type": "object",
    "properties": {"geojson": {"type": "string", "description": "GeoJSON data encoded as a UTF-8 string"}},
    "required": ["geojson"],
}


def _plain(title: str, description: str, required: tuple[str, ...] = ()) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object", "required": list(required)}


CONFIG = _plain("twin.Config", "The drive's full configuration: every option, seeds, map path and hash",
                ("config",))
EGO_STATE = _plain("twin.EgoState", "The ego state after one step, exact (floats round-trip through JSON)",
                   ("t", "step", "x", "y", "z", "yaw", "speed"))
UDM_RESPONSE = _plain("twin.UdmResponse", "One UDM answer, at the step it became available to the simulation",
                      ("step", "frame", "status", "features"))
UDM_LATENCY = _plain("twin.UdmLatency", "Monotonic-clock latency of one UDM query (client and loop)",
                     ("frame", "status"))
METRICS = _plain("twin.Metrics", "metrics.json of the drive, written at its end")


@dataclass(frozen=True)
class Channel:
    topic: str
    schema: dict[str, Any]

    @property
    def schema_name(self) -> str:
        return self.schema["title"]


CONFIG_CHANNEL = Channel("/config", CONFIG)
EGO_STATE_CHANNEL = Channel("/ego/state", EGO_STATE)
EGO_POSE_CHANNEL = Channel("/ego/pose", POSE_IN_FRAME)
TF_CHANNEL = Channel("/tf", FRAME_TRANSFORM)
GNSS_CHANNEL = Channel("/gnss", LOCATION_FIX)
UDM_SCENE_CHANNEL = Channel("/udm/scene", SCENE_UPDATE)
UDM_MAP_CHANNEL = Channel("/udm/geojson", GEOJSON)
UDM_RESPONSE_CHANNEL = Channel("/udm/response", UDM_RESPONSE)
UDM_LATENCY_CHANNEL = Channel("/udm/latency", UDM_LATENCY)
METRICS_CHANNEL = Channel("/metrics", METRICS)

CHANNELS = (CONFIG_CHANNEL, EGO_STATE_CHANNEL, EGO_POSE_CHANNEL, TF_CHANNEL, GNSS_CHANNEL, UDM_SCENE_CHANNEL,
            UDM_MAP_CHANNEL, UDM_RESPONSE_CHANNEL, UDM_LATENCY_CHANNEL, METRICS_CHANNEL)
