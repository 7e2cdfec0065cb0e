"""Material names and colours of the exported meshes: one per lane type / surface kind, one per mark colour.

Colours are linear RGBA in 0..1 (glTF baseColorFactor, OBJ Kd) and are also what the preview paints.
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.labelled import SURFACE_KINDS

KIND_COLOURS = {
    "driving": (0.22, 0.22, 0.24, 1.0),
    "sidewalk": (0.62, 0.60, 0.56, 1.0),
    "shoulder": (0.38, 0.38, 0.36, 1.0),
    "border": (0.45, 0.50, 0.40, 1.0),
    "biking": (0.55, 0.25, 0.22, 1.0),
    "parking": (0.30, 0.32, 0.42, 1.0),
    "median": (0.30, 0.48, 0.25, 1.0),
    "restricted": (0.50, 0.42, 0.25, 1.0),
    "curb": (0.75, 0.74, 0.70, 1.0),
    "junction": (0.26, 0.26, 0.28, 1.0),
    "roadmark": (0.95, 0.95, 0.95, 1.0),
    "object": (0.55, 0.55, 0.60, 1.0),
    "signal": (0.85, 0.70, 0.10, 1.0),
    "building": (0.80, 0.72, 0.62, 1.0),
    "other": (0.50, 0.50, 0.50, 1.0),
}
MARK_COLOUR_RGBA = {
    "white": (0.95, 0.95, 0.95, 1.0), "yellow": (0.95, 0.78, 0.10, 1.0), "red": (0.80, 0.10, 0.10, 1.0),
    "blue": (0.10, 0.25, 0.80, 1.0), "green": (0.10, 0.60, 0.20, 1.0), "orange": (0.95, 0.50, 0.05, 1.0),
    "violet": (0.55, 0.20, 0.70, 1.0), "black": (0.05, 0.05, 0.05, 1.0),
}


def kind_material(code: int) -> str:
    return SURFACE_KINDS[int(code)]


def mark_material(colour: str) -> str:
    return f"roadmark_{colour}"


def material_rgba(name: str) -> tuple[float, float, float, float]:
    if name.startswith("roadmark_"):
        return MARK_COLOUR_RGBA.get(name[len("roadmark_"):], KIND_COLOURS["roadmark"])
    return KIND_COLOURS.get(name, KIND_COLOURS["other"])


def rgb8(name: str) -> tuple[int, int, int]:
    r, g, b, _ = material_rgba(name)
    return tuple(round(255 * np.clip(c, 0, 1) ** (1 / 2.2)) for c in (r, g, b))
