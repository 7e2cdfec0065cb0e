"""Read an uncompressed ``.npz`` (what ``mesh.labelled.npz_bytes`` writes) in one pass over its bytes.

``np.load`` opens a ``zipfile.ZipFile``, then per member a ``ZipExtFile`` and ``ast.literal_eval`` of the
``.npy`` header: about 120 us per array, most of the time of the collision stage, which reads the mesh stage's
tens of thousands of labelled tiles with ten arrays each. Here the zip's central directory is unpacked with
``struct``, each member's CRC checked (as ``zipfile`` does), and the ``.npy`` header parsed with one regular
expression for the layout ``np.lib.format`` writes. Anything else -- compressed or zip64 members, another header
layout, object arrays -- goes to ``np.load``, so the arrays and the errors are always ``np.load``'s
(tests/test_npzfile.py compares both).
"""

from __future__ import annotations

import io
import re
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

_END = struct.Struct("<4s4H2LH")          # end of central directory record
_CENTRAL = struct.Struct("<4s6H3L5H2L")   # central directory entry
_LOCAL = struct.Struct("<4s5HL2L2H")      # local file header
_NPY_MAGIC = b"\x93NUMPY"
# the header np.lib.format.write_array writes: "{'descr': '<f8', 'fortran_order': False, 'shape': (5, 3), }"
_NPY_HEADER = re.compile(r"\{'descr': '([<>|=][a-zA-Z]\d*)', 'fortran_order': (False|True), "
                         r"'shape': \(((?:\d+, )*(?:\d+,?)?)\), \} *\n")
_DTYPES: dict[str, np.dtype] = {}


class _Unusual(Exception):
    """A layout the one-pass reader leaves to np.load."""


def read_npz(source: str | Path | bytes) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` (its path or its bytes) by name, as ``np.load(source, allow_pickle=False)``
    gives them (fresh, writable arrays); a damaged file raises what ``np.load`` raises for it (``BadZipFile``,
    ``ValueError``, ``EOFError``, ``OSError``; ``TypeError`` for a lone .npy array)."""
    if isinstance(source, bytes):
        data = source
    else:
        with open(source, "rb", buffering=0) as file:  # unbuffered: one read of the whole file
            data = file.readall()
    try:
        return _read_stored(data)
    except _Unusual:
        loaded = np.load(io.BytesIO(data), allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise TypeError("an .npy array, not an .npz archive") from None
        with loaded:
            return {name: loaded[name] for name in loaded.files}


def _read_stored(data: bytes) -> dict[str, np.ndarray]:
    if not data.startswith((b"PK\x03\x04", b"PK\x05\x06")):  # np.load's test for a zip
        raise _Unusual  # np.load tells an .npy, a pickle, garbage
    end = data.rfind(b"PK\x05\x06", max(0, len(data) - _END.size - 0xFFFF))
    if end < 0 or end + _END.size > len(data):
        raise zipfile.BadZipFile("File is not a zip file")
    _, disk, _, _, entries, size, start, _ = _END.unpack_from(data, end)
    if disk or entries == 0xFFFF or start == 0xFFFFFFFF or start + size > end:
        raise _Unusual  # multi-disk, zip64 or a directory not where it says: np.load judges
    arrays, at = {}, start
    for _ in range(entries):
        if at + _CENTRAL.size > end:
            raise zipfile.BadZipFile("Truncated central directory")
        (signature, _, _, flags, method, _, _, crc, packed, size, name_length, extra_length, comment_length,
         _, _, _, offset) = _CENTRAL.unpack_from(data, at)
        if signature != b"PK\x01\x02":
            raise zipfile.BadZipFile("Bad magic number for central directory")
        name = data[at + _CENTRAL.size:at + _CENTRAL.size + name_length]
        at += _CENTRAL.size + name_length + extra_length + comment_length
        if method != zipfile.ZIP_STORED or flags & 0x1 or packed != size or 0xFFFFFFFF in (size, offset):
            raise _Unusual
        if offset + _LOCAL.size > len(data):
            raise zipfile.BadZipFile("Truncated file header")
        local = _LOCAL.unpack_from(data, offset)
        if local[0] != b"PK\x03\x04":
            raise zipfile.BadZipFile("Bad magic number for file header")
        member_start = offset + _LOCAL.size + local[9] + local[10]
        if data[offset + _LOCAL.size:offset + _LOCAL.size + local[9]] != name:
            raise zipfile.BadZipFile(f"File name in directory {name!r} and header differ.")
        member = data[member_start:member_start + size]
        if len(member) != size:
            raise EOFError
        if zlib.crc32(member) != crc:
            raise zipfile.BadZipFile(f"Bad CRC-32 for file {name!r}")
        key = name.decode("utf-8" if flags & 0x800 else "ascii" if name.isascii() else "cp437")  # cp437: zipfile's default
        if not key.endswith(".npy") or not member.startswith(_NPY_MAGIC):
            raise _Unusual  # np.load gives such members as bytes or by another name
        arrays[key[:-4]] = _npy_array(member)
    return arrays


def _npy_array(member: bytes) -> np.ndarray:
    """The array of one ``.npy`` member with a header in np.lib.format's own layout."""
    major = member[6]
    if major == 1:
        header_start, header_length = 10, int.from_bytes(member[8:10], "little")
    elif major in (2, 3):
        header_start, header_length = 12, int.from_bytes(member[8:12], "little")
    else:
        raise _Unusual
    header_end = header_start + header_length
    match = _NPY_HEADER.fullmatch(member[header_start:header_end].decode("latin1"))
    if match is None:
        raise _Unusual
    descr, fortran, shape_text = match.groups()
    dtype = _DTYPES.get(descr)
    if dtype is None:
        dtype = np.dtype(descr)
        if dtype.hasobject:
            raise _Unusual  # np.load refuses it without pickle, with its own message
        _DTYPES[descr] = dtype
    shape = tuple(int(n) for n in shape_text.replace(",", " ").split())
    count = 1
    for n in shape:
        count *= n
    if header_end + count * dtype.itemsize > len(member):
        raise ValueError("EOF: reading array data, expected "
                         f"{count * dtype.itemsize} bytes got {len(member) - header_end}")
    array = np.frombuffer(member, dtype=dtype, count=count, offset=header_end).copy()
    if fortran == "True":
        return array.reshape(shape[::-1]).transpose()
    return array.reshape(shape)
