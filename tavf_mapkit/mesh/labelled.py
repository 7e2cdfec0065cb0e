"""LabelledMesh: the one value object every mesh producer returns and every consumer (export, preview,
collision world, twin) reads. Triangles keep which road / lane they belong to, so tools can pick a lane by face.

Coordinates are OpenDRIVE local metres (x east, y north, z up) in float64; exporters recentre and convert.
"""

from __future__ import annotations

import io
import struct
import sys
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Lane types and other surfaces get small integer codes so labels stay numpy arrays.
SURFACE_KINDS = ("driving", "sidewalk", "shoulder", "border", "biking", "parking", "median", "restricted",
                 "curb", "junction", "roadmark", "object", "signal", "building", "other")
KIND_CODE = {name: code for code, name in enumerate(SURFACE_KINDS)}


@dataclass(frozen=True, eq=False)
class LabelledMesh:
    vertices: np.ndarray     # (N, 3) float64, OpenDRIVE local coordinates
    faces: np.ndarray        # (M, 3) int64, counter-clockwise seen from outside (up for road surfaces)
    road_index: np.ndarray   # (M,) int32: row in OpenDriveMap.roads, -1 for none (buildings)
    lane_id: np.ndarray      # (M,) int32: OpenDRIVE lane id, 0 for none
    kind: np.ndarray         # (M,) int16: KIND_CODE of the lane type / surface kind
    uv: np.ndarray | None = None  # (N, 2) float64 (s, t) per vertex where that means something

    def __post_init__(self):
        m = len(self.faces)
        for name in ("road_index", "lane_id", "kind"):
            if len(getattr(self, name)) != m:
                raise ValueError(f"LabelledMesh.{name} has {len(getattr(self, name))} entries for {m} faces")

    @classmethod
    def empty(cls) -> LabelledMesh:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int32),
                   np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int16), np.zeros((0, 2)))

    @classmethod
    def concatenate(cls, meshes: list[LabelledMesh]) -> LabelledMesh:
        meshes = [m for m in meshes if len(m.faces)]
        if not meshes:
            return cls.empty()
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        with_uv = all(m.uv is not None for m in meshes)
        return cls(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]),
            np.concatenate([m.road_index for m in meshes]),
            np.concatenate([m.lane_id for m in meshes]),
            np.concatenate([m.kind for m in meshes]),
            np.concatenate([m.uv for m in meshes]) if with_uv else None,
        )

    def select(self, face_mask: np.ndarray) -> LabelledMesh:
        """The faces where ``face_mask`` is true (a mask or ascending indices), with unused vertices dropped."""
        return self.select_with_vertices(face_mask)[0]

    def select_with_vertices(self, face_mask: np.ndarray) -> tuple[LabelledMesh, np.ndarray]:
        """(``select(face_mask)``, the indices of the vertices it kept, ascending): for callers that carry
        per-vertex data of their own (``spill.Keyed``), without finding the used vertices twice."""
        used, faces = used_vertices(self.faces[face_mask], len(self.vertices))
        return self._rebuilt(self.vertices[used], faces, face_mask, None if self.uv is None else self.uv[used]), used

    def grouped(self, face_group: np.ndarray):
        """The same mesh with its faces (and vertices) ordered by ``face_group``, keeping their order inside a
        group; every vertex must belong to faces of one group. A batch of units reordered so is, unit by unit,
        what each unit gives meshed alone (``mesh.units``)."""
        face_group = np.asarray(face_group)
        order = np.argsort(face_group, kind="stable")
        vertex_group = np.zeros(len(self.vertices), dtype=face_group.dtype)
        vertex_group[self.faces[order].ravel()] = np.repeat(face_group[order], 3)
        vertex_order = np.argsort(vertex_group, kind="stable")
        new_index = np.empty(len(vertex_order), dtype=np.int64)
        new_index[vertex_order] = np.arange(len(vertex_order))
        return self._rebuilt(self.vertices[vertex_order], new_index[self.faces[order]], order,
                             None if self.uv is None else self.uv[vertex_order])

    def _rebuilt(self, vertices, faces, face_index, uv):
        """A mesh of the same class from new vertices / faces; per-face labels taken at ``face_index``."""
        return LabelledMesh(vertices, faces, self.road_index[face_index], self.lane_id[face_index],
                            self.kind[face_index], uv)

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    _ARRAYS = ("vertices", "faces", "road_index", "lane_id", "kind", "uv")

    def to_npz_bytes(self) -> bytes:
        """The arrays as an ``.npz`` (np.load reads it), byte-reproducible."""
        return npz_bytes({name: getattr(self, name) for name in self._ARRAYS})

    @classmethod
    def load_npz(cls, path: str | Path) -> LabelledMesh:
        with np.load(path, allow_pickle=False) as data:
            return cls(*(data.get(name, None) for name in cls._ARRAYS))


def used_vertices(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """(the vertices ``faces`` use, ascending; the faces renumbered to them, int64): ``np.unique(faces,
    return_inverse=True)``, found with a mask over the ``vertex_count`` vertices instead of sorting the corners
    (selections of tiles and units from a merged mesh are most of the mesh stage's calls)."""
    faces = np.asarray(faces)
    if not faces.size:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64)
    mask = np.zeros(vertex_count, dtype=bool)
    mask[faces.ravel()] = True
    used = np.flatnonzero(mask)
    # new numbers written at the used vertices only: a cumsum over all ``vertex_count`` was most of the time of
    # cutting a final tile's few faces from a merged spill tile
    new_index = np.empty(vertex_count, dtype=np.int64)
    new_index[used] = np.arange(len(used))
    return used, new_index[faces].reshape(-1, 3)


def npz_bytes(arrays: dict[str, np.ndarray | None]) -> bytes:
    """Arrays (None ones left out) as an uncompressed ``.npz``; fixed zip timestamps make it byte-reproducible.

    The zip is written directly, byte for byte what ``zipfile`` writes for ``writestr(ZipInfo(name,
    date_time=(1980, 1, 1, 0, 0, 0)), data)`` with ZIP_STORED into a seekable buffer (tests/test_mesh_npz.py
    compares both): zipfile's per-member bookkeeping was most of the time of a build's thousands of labelled
    tiles."""
    headers, central, offset = [], [], 0
    for name, value in arrays.items():
        if value is None:
            continue
        member = io.BytesIO()
        np.lib.format.write_array(member, np.ascontiguousarray(value), allow_pickle=False)
        data = member.getvalue()
        filename = f"{name}.npy".encode("ascii")
        if len(data) > _ZIP64_MEMBER:
            return _npz_bytes_zipfile(arrays)  # zip64 records: leave them to zipfile
        crc = zlib.crc32(data)
        fields = (_ZIP_VERSION, 0, zipfile.ZIP_STORED, 0, _DOS_DATE_1980, crc, len(data), len(data), len(filename))
        local = struct.pack("<4s5HL2L2H", b"PK\x03\x04", *fields, 0) + filename
        central.append(struct.pack("<4s6H3L5H2L", b"PK\x01\x02", _ZIP_VERSION | _CREATE_SYSTEM << 8,
                                   *fields, 0, 0, 0, 0, _EXTERNAL_ATTR, offset) + filename)
        headers.append(local + data)
        offset += len(local) + len(data)
    directory = b"".join(central)
    if offset + len(directory) > _ZIP64_MEMBER:
        return _npz_bytes_zipfile(arrays)
    end = struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, len(central), len(central), len(directory), offset, 0)
    return b"".join(headers) + directory + end


_ZIP_VERSION = 20                       # zipfile's default "version needed" / "made by"
_CREATE_SYSTEM = 0 if sys.platform == "win32" else 3
_EXTERNAL_ATTR = 0o600 << 16            # what zipfile gives a member written without attributes
_DOS_DATE_1980 = (0 << 9) | (1 << 5) | 1  # 1980-01-01; the DOS time 00:00:00 is 0
_ZIP64_MEMBER = 0x7FFFFFFF // 2         # members this large need zip64 records (zipfile's own threshold is lower)


def _npz_bytes_zipfile(arrays: dict[str, np.ndarray | None]) -> bytes:
    """``npz_bytes`` through ``zipfile`` (the reference the direct writer is checked against)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, value in arrays.items():
            if value is None:
                continue
            member = io.BytesIO()
            np.lib.format.write_array(member, np.ascontiguousarray(value), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), member.getvalue())
    return buffer.getvalue()
