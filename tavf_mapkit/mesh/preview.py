"""Top view PNG of the exported meshes: lanes coloured by type, junctions, marks and solids on top.

Painted piece by piece (a tile at a time) on one mask per material: the triangles of one material all have
its colour, so only the order of the materials matters (lanes, then marks, then solids, each by code; later
ones cover earlier ones), and the masks are laid on the image in that order at the end. The picture is the
same as painting every material's triangles of the whole map in turn, with memory for the masks only.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from tavf_mapkit.fileutil import write_bytes_atomic
from tavf_mapkit.mesh.materials import rgb8

BACKGROUND = (250, 250, 247)
LAYERS = ("lanes", "marks", "solids")
MAX_PIXELS = 2048
MARGIN = 8


class PreviewCanvas:
    """The preview of a map whose plan-view vertex bounds are (low, high); paint() any number of times."""

    def __init__(self, low, high, max_pixels: int = MAX_PIXELS, margin: int = MARGIN):
        from PIL import Image

        self.empty = low is None or high is None
        self.masks: dict[tuple, tuple[str, object, object]] = {}
        if self.empty:
            self.image = Image.new("RGB", (64, 64), BACKGROUND)
            return
        self.low = np.asarray(low, dtype=float)
        extent = np.maximum(np.asarray(high, dtype=float) - self.low, 1e-6)
        self.scale = (max_pixels - 2 * margin) / float(extent.max())
        self.margin = margin
        width, height = (np.ceil(extent * self.scale).astype(int) + 2 * margin)
        self.size = (int(width), int(height))

    def paints(self, layer: str) -> bool:
        # paint narrower than a pixel would only speckle the lanes
        return not (layer == "marks" and self.scale < 8.0)

    def paint(self, layer: str, material: str, code: int, mesh) -> None:
        """Paint the triangles of one material (``code``: its kind or colour code, which orders materials)."""
        if self.empty or not self.paints(layer) or not len(mesh.faces):
            return
        draw = self._mask((LAYERS.index(layer), int(code)), material)[1]
        xy = (mesh.vertices[:, :2] - self.low) * self.scale + self.margin
        xy[:, 1] = self.size[1] - xy[:, 1]  # north up
        for triangle in xy[mesh.faces].reshape(-1, 6).tolist():  # x0, y0, x1, y1, x2, y2: no tuples to make
            draw.polygon(triangle, fill=255)

    def _mask(self, key: tuple, material: str):
        from PIL import Image, ImageDraw

        if key not in self.masks:
            mask = Image.new("L", self.size, 0)
            self.masks[key] = (material, mask, ImageDraw.Draw(mask))
        return self.masks[key][1:]

    def painted(self) -> list:
        """(key, material, box, bytes) of every mask, cropped to what was painted: the paint of a canvas of the
        same map made elsewhere (a Dask task, ``mesh.remote``), for ``add_painted``. Masks are all-or-nothing
        (255 where any triangle covers a pixel), so adding them in any order gives the same image."""
        out = []
        for key, (material, mask, _) in sorted(self.masks.items()):
            box = mask.getbbox()
            if box is not None:
                out.append((key, material, box, mask.crop(box).tobytes()))
        return out

    def add_painted(self, painted: list) -> None:
        from PIL import Image, ImageChops

        for key, material, box, data in painted:
            mask = self._mask(key, material)[0]
            part = Image.frombytes("L", (box[2] - box[0], box[3] - box[1]), data)
            mask.paste(ImageChops.lighter(mask.crop(box), part), box)

    def render(self):
        from PIL import Image

        if self.empty:
            return self.image
        image = Image.new("RGB", self.size, BACKGROUND)
        for key in sorted(self.masks):
            material, mask, _ = self.masks[key]
            image.paste(rgb8(material), mask=mask)
        return image

    def save(self, path: str | Path) -> None:
        buffer = io.BytesIO()
        self.render().save(buffer, format="PNG", optimize=False)
        write_bytes_atomic(path, buffer.getvalue())


def group_code(layer: str, material: str) -> int:
    """The code that orders a material inside its layer (kind code; colour index for marks)."""
    from tavf_mapkit.mesh.labelled import KIND_CODE
    from tavf_mapkit.mesh.marks import MARK_COLOURS

    if layer == "marks":
        return MARK_COLOURS.index(material.removeprefix("roadmark_"))
    return KIND_CODE[material]


def render_preview(layers, max_pixels: int = MAX_PIXELS, margin: int = MARGIN):
    """A PIL image of the plan view (north up), at most ``max_pixels`` on the longer side."""
    groups = layers.groups()
    points = [mesh.vertices[:, :2] for _, _, mesh in groups if len(mesh.vertices)]
    if not points:
        return PreviewCanvas(None, None).render()
    allp = np.concatenate(points)
    canvas = PreviewCanvas(allp.min(axis=0), allp.max(axis=0), max_pixels, margin)
    for layer, material, mesh in groups:
        canvas.paint(layer, material, group_code(layer, material), mesh)
    return canvas.render()


def write_preview(layers, path: str | Path, max_pixels: int = MAX_PIXELS) -> None:
    buffer = io.BytesIO()
    render_preview(layers, max_pixels).save(buffer, format="PNG", optimize=False)
    write_bytes_atomic(path, buffer.getvalue())
