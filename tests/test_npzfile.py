"""read_npz gives what np.load gives -- the same arrays, or an error for a damaged file -- for the files the mesh
stage writes (npz_bytes) and for numpy's own .npz files."""

import io
import zipfile

import numpy as np
import pytest

from tavf_mapkit.mesh.labelled import npz_bytes
from tavf_mapkit.npzfile import read_npz
from tavf_mapkit.world.build import TILE_READ_ERRORS


def _arrays():
    rng = np.random.default_rng(3)
    return {
        "vertices": rng.random((40, 3)) * 1e4, "faces": rng.integers(0, 40, (30, 3)),
        "kind": rng.integers(0, 14, 30).astype(np.int16), "lane_id": rng.integers(-3, 4, 30).astype(np.int32),
        "empty": np.zeros((0, 3)), "scalar": np.array(2.5), "flags": rng.random(7) > 0.5,
        "text": np.array(["curb", "building", "x" * 300]), "bytes": np.array([b"ab", b"c"]),
        "fortran": np.asfortranarray(rng.random((5, 7))), "big_endian": np.arange(6, dtype=">i4").reshape(2, 3),
        "wide": np.arange(3 * 70000, dtype=np.int64).reshape(70000, 3)}


def _np_load(data: bytes) -> dict:
    with np.load(io.BytesIO(data), allow_pickle=False) as loaded:
        return {name: loaded[name] for name in loaded.files}


def _same(got: dict, want: dict) -> None:
    assert list(got) == list(want)
    for name, value in want.items():
        assert got[name].dtype == value.dtype and got[name].shape == value.shape, name
        assert np.array_equal(got[name], value), name
        assert got[name].flags.f_contiguous == value.flags.f_contiguous, name
        assert got[name].flags.writeable and got[name].flags.aligned, name


def _numpy_savez(compressed: bool) -> bytes:
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **_arrays())
    return buffer.getvalue()


@pytest.mark.parametrize("make", [lambda: npz_bytes(_arrays()), lambda: npz_bytes({}),
                                  lambda: _numpy_savez(False), lambda: _numpy_savez(True)],
                         ids=["npz_bytes", "empty", "np.savez", "np.savez_compressed"])
def test_read_npz_gives_np_loads_arrays(make, tmp_path, monkeypatch, request):
    data = make()
    want = _np_load(data)
    if "compressed" not in request.node.name:  # read in one pass: np.load is not asked
        monkeypatch.setattr(np, "load", None)
    _same(read_npz(data), want)
    (tmp_path / "a.npz").write_bytes(data)
    _same(read_npz(tmp_path / "a.npz"), want)


def test_arrays_are_independent_of_each_other_and_of_the_file():
    arrays = read_npz(npz_bytes({"a": np.arange(4.0), "b": np.arange(3)}))
    arrays["a"][0] = 9.0
    assert arrays["b"].tolist() == [0, 1, 2] and arrays["a"].tolist() == [9.0, 1.0, 2.0, 3.0]


def _damaged():
    data = npz_bytes(_arrays())
    member = data.index(b"\x93NUMPY", 100)
    header = data.index(b"'descr'", member)
    yield "truncated", data[: len(data) // 2]
    yield "tail cut", data[:-1]
    yield "not a zip", b"not a zip"
    yield "empty file", b""
    yield "array data changed", data[:member + 200] + bytes([data[member + 200] ^ 1]) + data[member + 201:]
    yield "header changed", data[:header] + b"'dascr'" + data[header + 7:]
    yield "npy, not npz", _npy_bytes()


def _npy_bytes() -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, np.arange(3))
    return buffer.getvalue()


@pytest.mark.parametrize("case", list(_damaged()), ids=[name for name, _ in _damaged()])
def test_a_damaged_file_raises_a_tile_read_error(case):
    name, data = case
    with pytest.raises(TILE_READ_ERRORS):
        read_npz(data)
    if name != "npy, not npz":  # np.load gives that one as an array
        with pytest.raises(TILE_READ_ERRORS):
            _np_load(data)


def test_an_object_array_is_refused_without_pickle():
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        member = io.BytesIO()
        np.lib.format.write_array(member, np.array([{"a": 1}], dtype=object), allow_pickle=True)
        archive.writestr("o.npy", member.getvalue())
    with pytest.raises(ValueError, match="allow_pickle"):
        read_npz(buffer.getvalue())
