"""A small glTF 2.0 binary (.glb) writer for triangle meshes with PBR colour materials.

Written with numpy rather than through trimesh's scene exporter because a map has hundreds of tiles and the
per-file overhead there dominated the export time; the files are plain glTF 2.0 (one mesh + node per
material, POSITION / TEXCOORD_0 float32, uint32 indices) and the tests load them back with trimesh.
"""

from __future__ import annotations

import json
import struct

import numpy as np

_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125
_TRIANGLES = 4


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * ((4 - len(data) % 4) % 4)


def glb_bytes(parts: list[dict], generator: str = "tavf-mapkit") -> bytes:
    """parts: dicts with name, positions (N, 3) float32 in glTF axes, indices (M, 3), optional uv (N, 2),
    rgba (4 floats), double_sided (bool)."""
    blobs: list[bytes] = []
    offset = 0
    buffer_views, accessors, materials, meshes, nodes = [], [], [], [], []

    def add_view(data: bytes, target: int) -> int:
        nonlocal offset
        buffer_views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data), "target": target})
        padded = _pad(data, b"\x00")
        blobs.append(padded)
        offset += len(padded)
        return len(buffer_views) - 1

    for part in parts:
        positions = np.ascontiguousarray(part["positions"], dtype="<f4")
        indices = np.ascontiguousarray(part["indices"], dtype="<u4")
        if not len(indices):
            continue
        attributes = {}
        view = add_view(positions.tobytes(), _ARRAY_BUFFER)
        accessors.append({"bufferView": view, "componentType": _FLOAT, "count": len(positions), "type": "VEC3",
                          "min": positions.min(axis=0).tolist(), "max": positions.max(axis=0).tolist()})
        attributes["POSITION"] = len(accessors) - 1
        if part.get("uv") is not None:
            uv = np.ascontiguousarray(part["uv"], dtype="<f4")
            view = add_view(uv.tobytes(), _ARRAY_BUFFER)
            accessors.append({"bufferView": view, "componentType": _FLOAT, "count": len(uv), "type": "VEC2"})
            attributes["TEXCOORD_0"] = len(accessors) - 1
        view = add_view(indices.tobytes(), _ELEMENT_ARRAY_BUFFER)
        accessors.append({"bufferView": view, "componentType": _UNSIGNED_INT, "count": int(indices.size),
                          "type": "SCALAR"})
        index_accessor = len(accessors) - 1
        materials.append({"name": part["name"], "doubleSided": bool(part.get("double_sided", False)),
                          "pbrMetallicRoughness": {"baseColorFactor": [float(c) for c in part["rgba"]],
                                                   "metallicFactor": 0.0, "roughnessFactor": 0.9}})
        meshes.append({"name": part["name"], "primitives": [{"attributes": attributes, "indices": index_accessor,
                                                             "material": len(materials) - 1, "mode": _TRIANGLES}]})
        nodes.append({"name": part["name"], "mesh": len(meshes) - 1})
    binary = b"".join(blobs)
    document = {
        "asset": {"version": "2.0", "generator": generator},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes, "meshes": meshes, "materials": materials, "accessors": accessors,
        "bufferViews": buffer_views,
        "buffers": [{"byteLength": len(binary)}] if binary else [],
    }
    if not binary:
        document.pop("buffers")
        for key in ("bufferViews", "accessors", "meshes", "materials", "nodes"):
            document[key] = []
    json_chunk = _pad(json.dumps(document, separators=(",", ":")).encode("utf-8"), b" ")
    chunks = struct.pack("<II", len(json_chunk), 0x4E4F534A) + json_chunk
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks
