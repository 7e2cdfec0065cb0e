"""The preview canvas (mesh/preview.py) paints a real map's triangles exactly as drawing each one as a polygon of
three points does."""

from __future__ import annotations

from PIL import Image, ImageDraw

from tavf_mapkit.mesh.preview import PreviewCanvas
from tavf_mapkit.mesh.surface import build_road_surface
from tavf_mapkit.opendrive import load_opendrive


def test_painted_mask_equals_triangle_by_triangle_polygons(shared):
    odr = load_opendrive(shared("xodr", "esmini", "fabriksgatan.xodr"))
    mesh = build_road_surface(odr, 0.05).mesh
    plan = mesh.vertices[:, :2]
    canvas = PreviewCanvas(plan.min(axis=0), plan.max(axis=0))
    canvas.paint("lanes", "driving", 0, mesh)
    (_, mask, _), = canvas.masks.values()
    expected = Image.new("L", canvas.size, 0)
    draw = ImageDraw.Draw(expected)
    xy = (plan - canvas.low) * canvas.scale + canvas.margin
    xy[:, 1] = canvas.size[1] - xy[:, 1]
    for triangle in xy[mesh.faces].tolist():
        draw.polygon([tuple(point) for point in triangle], fill=255)
    assert mask.tobytes() == expected.tobytes()
    assert 0 < sum(mask.histogram()[255:]) < canvas.size[0] * canvas.size[1]
