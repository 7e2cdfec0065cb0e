"""Lane surface meshes of every lane of every road, on the adaptive samples, with curb faces.

Per sample of a lane section the cross-section is a polyline across all lanes: the centre border
(t = laneOffset) and each lane's outer border. Adjacent lanes share their border vertex (no cracks) unless
their heights differ there; then each keeps its own edge and a vertical curb face joins the two. The
outermost lane of a side that is raised gets a face down to the road level (h = 0) as well.

Faces are counter-clockwise seen from the side their normal points to: up (along e_h) for lane surfaces,
from the raised lane towards the lower side for curb faces.
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.adaptive import LEFT_LIMIT, AdaptiveSamples
from tavf_mapkit.mesh.cleanup import face_cross, proper_faces
from tavf_mapkit.mesh.kinds import lane_kind_codes
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.opendrive.sampling import sample_lanes_at
from tavf_mapkit.opendrive.surface import surface_frame


def _outermost(arrays) -> np.ndarray:
    """Per lane row: is it the outermost lane of its side of its section?"""
    n = len(arrays.lane_id)
    nxt = np.arange(1, n + 1).clip(max=n - 1)
    continues = ((arrays.lane_section[nxt] == arrays.lane_section) & (np.sign(arrays.lane_id[nxt])
                 == np.sign(arrays.lane_id)) & (arrays.lane_rank[nxt] == arrays.lane_rank + 1))
    continues[n - 1:] = False
    return ~continues


def _orient(vertices, faces, desired) -> np.ndarray:
    """Faces flipped where their normal points against ``desired`` (per face vectors)."""
    flip = np.einsum("ij,ij->i", face_cross(vertices, faces), desired) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def lane_meshes(odr, samples: AdaptiveSamples) -> LabelledMesh:
    """Lane surfaces and curb faces of every lane section on the given samples (junction roads included)."""
    return build_lane_meshes(odr, sample_lanes_at(odr, samples.section, samples.s))[0]


def raised_lane_rows(arrays) -> np.ndarray:
    """Per lane row: does the lane have a non-zero height anywhere?"""
    raised = np.zeros(len(arrays.lane_id), dtype=bool)
    for table in (arrays.lane_height_inner, arrays.lane_height_outer):
        nonzero = np.any(table.coefficients != 0.0, axis=1)
        raised[table.group[nonzero]] = True
    return raised


def build_lane_meshes(odr, sampling) -> tuple[LabelledMesh, np.ndarray]:
    """(mesh, lane row of every face) for a sampling of lane sections (``sample_lanes_at``)."""
    arrays = odr.arrays
    n_pairs = len(sampling.pair_lane)
    n_samples = len(sampling.sample_s)
    if not n_pairs:
        return LabelledMesh.empty(), np.zeros(0, dtype=np.int64)
    e_t, e_h = surface_frame(sampling.heading, sampling.slope, sampling.superelevation)
    h_in, h_out = sampling.heights()
    lane = sampling.pair_lane
    sample = sampling.pair_sample
    rank = arrays.lane_rank[lane]
    side = np.sign(arrays.lane_id[lane]).astype(float)
    per_section = np.bincount(sampling.sample_section, minlength=len(arrays.section_s0))
    stride = per_section[arrays.lane_section[lane]]  # pairs between a lane and its inner neighbour
    pairs = np.arange(n_pairs)

    # vertices: outer edges [0, P), centre line [P, P+S), own inner edges, ground edges under raised outer edges
    centre_index = n_pairs + sample
    prev_edge = np.where(rank == 0, centre_index, pairs - stride)
    prev_height = np.where(rank == 0, 0.0, h_out[np.maximum(pairs - stride, 0)])
    own_inner = h_in != prev_height
    inner_index = prev_edge.copy()
    inner_index[own_inner] = n_pairs + n_samples + np.arange(np.count_nonzero(own_inner))
    raised_outer = (h_out != 0.0) & _outermost(arrays)[lane]
    ground_index = pairs.copy()
    base = n_pairs + n_samples + np.count_nonzero(own_inner)
    ground_index[raised_outer] = base + np.arange(np.count_nonzero(raised_outer))

    centre = np.column_stack([sampling.ref_x, sampling.ref_y, sampling.ref_z]) + sampling.lane_offset[:, None] * e_t
    vertices = np.concatenate([
        sampling.points_at(sampling.t_outer, h_out),
        centre,
        _points(sampling, e_t, e_h, own_inner, sampling.t_inner, h_in),
        _points(sampling, e_t, e_h, raised_outer, sampling.t_outer, None),
    ])
    s_pair = sampling.s
    uv = np.concatenate([
        np.column_stack([s_pair, sampling.t_outer]),
        np.column_stack([sampling.sample_s, sampling.lane_offset]),
        np.column_stack([s_pair[own_inner], sampling.t_inner[own_inner]]),
        np.column_stack([s_pair[raised_outer], sampling.t_outer[raised_outer]]),
    ])

    # quads between consecutive samples of the same lane (pairs are lane by lane in sample order)
    p0 = pairs[:-1][lane[1:] == lane[:-1]]
    p1 = p0 + 1
    up = e_h[sample[p0]]
    i0, i1, o0, o1 = inner_index[p0], inner_index[p1], pairs[p0], pairs[p1]
    surface = np.concatenate([np.column_stack([i0, o0, o1]), np.column_stack([i0, o1, i1])])
    up2 = np.concatenate([up, up])
    down = np.einsum("ij,ij->i", face_cross(vertices, surface), up2) < 0
    # a seam bridges a jump of the exact surface at a kink (two cross-sections LEFT_LIMIT apart): its
    # triangles fill the wedge on the convex side; on the concave side they would fold over, so they go
    seam = np.tile(s_pair[p1] - s_pair[p0] < 10 * LEFT_LIMIT, 2)
    keep = ~(seam & down)
    surface = _orient(vertices, surface[keep], up2[keep])
    surface_pair = np.concatenate([p0, p0])[keep]
    parts = [(surface, surface_pair, lane_kind_codes(arrays.lane_type[lane[surface_pair]]))]

    # curb faces: between the inward edge and this lane's own inner edge, wherever heights differ
    curb = own_inner[p0] | own_inner[p1]
    c0 = p0[curb]
    c1 = c0 + 1
    faces, direction = _vertical_quads(prev_edge[c0], inner_index[c0], prev_edge[c1], inner_index[c1],
                                       side[c0][:, None] * e_t[sample[c0]] *
                                       np.sign((prev_height - h_in)[c0] + (prev_height - h_in)[c1])[:, None])
    parts.append((_orient(vertices, faces, direction), np.concatenate([c0, c0]),
                  np.full(2 * len(c0), KIND_CODE["curb"], dtype=np.int16)))
    # skirts under the raised outer edge of a side's outermost lane
    skirt = raised_outer[p0] | raised_outer[p1]
    k0 = p0[skirt]
    k1 = k0 + 1
    faces, direction = _vertical_quads(pairs[k0], ground_index[k0], pairs[k1], ground_index[k1],
                                       side[k0][:, None] * e_t[sample[k0]] *
                                       np.sign(h_out[k0] + h_out[k1])[:, None])
    parts.append((_orient(vertices, faces, direction), np.concatenate([k0, k0]),
                  np.full(2 * len(k0), KIND_CODE["curb"], dtype=np.int16)))

    faces = np.concatenate([p[0] for p in parts]).astype(np.int64)
    face_pair = np.concatenate([p[1] for p in parts])
    kind = np.concatenate([p[2] for p in parts]).astype(np.int16)
    keep = proper_faces(vertices, faces)
    face_pair = face_pair[keep]
    mesh = LabelledMesh(vertices, faces[keep], sampling.road_index[face_pair].astype(np.int32),
                        arrays.lane_id[lane[face_pair]].astype(np.int32), kind[keep], uv)
    return mesh.select(np.ones(len(mesh.faces), dtype=bool)), lane[face_pair]


def _points(sampling, e_t, e_h, mask, t, h) -> np.ndarray:
    """Surface points of the masked pairs at offsets t (and heights h)."""
    i = sampling.pair_sample[mask]
    points = np.column_stack([sampling.ref_x[i], sampling.ref_y[i], sampling.ref_z[i]]) + t[mask][:, None] * e_t[i]
    if h is not None:
        points += h[mask][:, None] * e_h[i]
    return points


def _vertical_quads(a0, b0, a1, b1, direction):
    """Two triangles per quad (edge a -> edge b, from sample 0 to 1) and their desired normal direction."""
    faces = np.concatenate([np.column_stack([a0, b0, b1]), np.column_stack([a0, b1, a1])])
    return faces, np.concatenate([direction, direction])
