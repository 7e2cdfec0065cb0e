"""Wavefront OBJ for collision meshes: positions and triangles only (pybullet and trimesh read it).

Coordinates are written relative to the world origin with 0.1 mm resolution, so the numbers stay small
and identical input gives byte-identical files.
"""

from __future__ import annotations

import numpy as np


def obj_text(name: str, vertices: np.ndarray, faces: np.ndarray, comment: str = "") -> str:
    """OBJ text of a triangle mesh (vertices already recentred)."""
    vertices = np.round(np.asarray(vertices, dtype=np.float64), 4) + 0.0  # + 0.0 turns -0.0 into 0.0
    header = f"# {comment}\n" if comment else ""
    # tolist: Python numbers format a third faster than numpy scalars, to the same text
    return (f"{header}o {name}\n"
            + ("v %.4f %.4f %.4f\n" * len(vertices)) % tuple(vertices.ravel().tolist())
            + ("f %d %d %d\n" * len(faces)) % tuple((np.asarray(faces, dtype=np.int64) + 1).ravel().tolist()))
