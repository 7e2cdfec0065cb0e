"""npz_bytes writes its zip directly: the bytes must be zipfile's, and np.load must read the arrays back."""

import io

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh, _npz_bytes_zipfile, npz_bytes
from tavf_mapkit.mesh.solids import SceneSolids, Solid


def _cases():
    rng = np.random.default_rng(7)
    mesh = LabelledMesh(rng.random((40, 3)) * 1e4, rng.integers(0, 40, (30, 3)), rng.integers(-1, 900, 30).astype(np.int32),
                        rng.integers(-3, 4, 30).astype(np.int32), rng.integers(0, 14, 30).astype(np.int16),
                        rng.random((40, 2)))
    solids = SceneSolids((Solid("curb", mesh, "road 1 lane -2"), Solid("building", mesh, "way 7")), ("a: b",))
    yield {}
    yield {"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3), dtype=np.int64), "uv": None}
    yield {name: getattr(mesh, name) for name in LabelledMesh._ARRAYS}
    yield {f"solids_{name}": value for name, value in solids.arrays().items()}
    yield {"fortran": np.asfortranarray(rng.random((5, 7))), "strided": rng.random(20)[::3], "long": np.array(["x" * 500])}


def test_npz_bytes_are_zipfiles_bytes_and_load_back():
    for arrays in _cases():
        data = npz_bytes(arrays)
        assert data == _npz_bytes_zipfile(arrays)
        with np.load(io.BytesIO(data), allow_pickle=False) as loaded:
            kept = {name: value for name, value in arrays.items() if value is not None}
            assert sorted(loaded.files) == sorted(kept)
            for name, value in kept.items():
                assert loaded[name].dtype == value.dtype and np.array_equal(loaded[name], value)
