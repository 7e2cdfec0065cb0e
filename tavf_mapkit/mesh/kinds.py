"""OpenDRIVE lane types -> the surface kinds of ``LabelledMesh`` (``labelled.KIND_CODE``)."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.labelled import KIND_CODE

# Every lane type of OpenDRIVE 1.4-1.8; unknown types are "other".
LANE_TYPE_KIND = {
    "driving": "driving", "entry": "driving", "exit": "driving", "onramp": "driving", "offramp": "driving",
    "connectingramp": "driving", "bidirectional": "driving", "bus": "driving", "taxi": "driving",
    "hov": "driving", "sliplane": "driving", "mwyentry": "driving", "mwyexit": "driving",
    "special1": "driving", "special2": "driving", "special3": "driving",
    "sidewalk": "sidewalk", "walking": "sidewalk",
    "shoulder": "shoulder", "stop": "shoulder",
    "border": "border", "none": "border",
    "biking": "biking", "bike": "biking",
    "parking": "parking",
    "median": "median",
    "restricted": "restricted", "roadworks": "restricted",
    "curb": "curb",
    "rail": "other", "tram": "other",
}

#: kinds a vehicle drives on (their normals must point up)
DRIVABLE_KINDS = ("driving", "biking", "parking", "junction", "shoulder", "restricted")


def lane_kind_codes(lane_types: np.ndarray) -> np.ndarray:
    """int16 KIND_CODE for an array of OpenDRIVE lane type strings (case-insensitive)."""
    names, inverse = np.unique(np.asarray(lane_types, dtype=str), return_inverse=True)
    codes = np.array([KIND_CODE[LANE_TYPE_KIND.get(name.lower(), "other")] for name in names], dtype=np.int16)
    return codes[inverse.ravel()] if len(names) else np.zeros(0, dtype=np.int16)
