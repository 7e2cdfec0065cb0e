"""Top view PNG of the exported meshes: lanes coloured by type, junctions, marks and solids on top."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from tavf_mapkit.fileutil import write_bytes_atomic
from tavf_mapkit.mesh.materials import rgb8

BACKGROUND = (250, 250, 247)


def render_preview(layers, max_pixels: int = 2048, margin: int = 8):
    """A PIL image of the plan view (north up), at most ``max_pixels`` on the longer side."""
    from PIL import Image, ImageDraw

    groups = layers.groups()
    points = [mesh.vertices[:, :2] for _, _, mesh in groups if len(mesh.vertices)]
    if not points:
        return Image.new("RGB", (64, 64), BACKGROUND)
    allp = np.concatenate(points)
    low, high = allp.min(axis=0), allp.max(axis=0)
    extent = np.maximum(high - low, 1e-6)
    scale = (max_pixels - 2 * margin) / float(extent.max())
    width, height = (np.ceil(extent * scale).astype(int) + 2 * margin)
    image = Image.new("RGB", (int(width), int(height)), BACKGROUND)
    draw = ImageDraw.Draw(image)
    # painters' order: lanes, then marks, then solids (buildings last, they stand on top)
    for layer, material, mesh in groups:
        if layer == "marks" and scale < 8.0:
            continue  # paint narrower than a pixel: it would only speckle the lanes
        xy = (mesh.vertices[:, :2] - low) * scale + margin
        xy[:, 1] = height - xy[:, 1]  # north up
        colour = rgb8(material)
        for triangle in xy[mesh.faces].tolist():
            draw.polygon([tuple(p) for p in triangle], fill=colour)
    return image


def write_preview(layers, path: str | Path, max_pixels: int = 2048) -> None:
    buffer = io.BytesIO()
    render_preview(layers, max_pixels).save(buffer, format="PNG", optimize=False)
    write_bytes_atomic(path, buffer.getvalue())
