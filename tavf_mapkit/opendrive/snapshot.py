"""A loaded map saved as it lies in memory, so that the next reader of the same file need not parse it again.

Parsing is most of a region's start-up: the twin's setup on Maribor (31,667 roads, 408 MB of OpenDRIVE) spent
~30 s of its 50 s in the reader, Columbus (155,528 roads) 12 minutes; the same map comes back from a snapshot
in a tenth of that. The build writes ``NAME.odrmap`` beside ``NAME.xodr`` (stage "opendrive", from the file as
written: a snapshot is exactly what ``load_opendrive(NAME.xodr)`` returns), and every later reader of the build
(mesh, check and report stages, the twin) takes ``load_build_map``.

A snapshot is used only for the file it was made from (its sha256, checked against the file itself, not a
manifest) and by the code that made it (a key over the model's source and the Python and numpy versions);
anything else -- no snapshot, another file, other code, a damaged or foreign file -- reads the OpenDRIVE as
before. It is a pickle read by an unpickler that knows only the model's own classes and numpy's array
constructors (never ``getattr``, modules or functions at large): a snapshot from elsewhere cannot run code.
"""

from __future__ import annotations

import hashlib
import logging
import pickle
import sys
from dataclasses import fields, is_dataclass, replace
from functools import lru_cache
from importlib import import_module
from operator import attrgetter
from pathlib import Path

import numpy as np

from tavf_mapkit.memory import collector_paused
from tavf_mapkit.opendrive.network import OpenDriveMap

log = logging.getLogger(__name__)

SUFFIX = ".odrmap"
_MAGIC = b"tavf-mapkit odrmap 1\n"
_KEY_BYTES = 32

#: the model's classes a snapshot may hold, by module; nothing else is looked up while loading one
_MODEL = {
    "tavf_mapkit.opendrive.cubic": {"CubicProfile"},
    "tavf_mapkit.opendrive.diagnostics": {"Diagnostic"},
    "tavf_mapkit.opendrive.header": {"Header", "Offset"},
    "tavf_mapkit.opendrive.junction": {"Connection", "Controller", "Junction", "JunctionController", "LaneLink"},
    "tavf_mapkit.opendrive.lane": {"Lane", "LaneHeight", "LaneRecord", "RoadMark", "RoadMarkLine"},
    "tavf_mapkit.opendrive.lanesection": {"LaneSection"},
    "tavf_mapkit.opendrive.network": {"OpenDriveMap"},
    "tavf_mapkit.opendrive.objects": {"ObjectRepeat", "Outline", "OutlineCorner", "RoadObject", "Signal",
                                      "SignalReference"},
    "tavf_mapkit.opendrive.refline": {"reference_line_from_narrow"},
    "tavf_mapkit.opendrive.road": {"Road", "RoadLink", "RoadType", "ShapeRecord"},
    "tavf_mapkit.opendrive.snapshot": {"_made", "_part"},
}
#: numpy's own array and dtype constructors, under their numpy 2 and numpy 1 module names
_NUMPY = {("numpy", "dtype"), ("numpy", "ndarray"), ("numpy._core.numeric", "_frombuffer"),
          ("numpy.core.numeric", "_frombuffer"), ("numpy._core.multiarray", "_reconstruct"),
          ("numpy.core.multiarray", "_reconstruct")}


def snapshot_path(xodr: str | Path) -> Path:
    return Path(xodr).with_suffix(SUFFIX)


@lru_cache(maxsize=1)
def code_key() -> bytes:
    """What a snapshot's objects depend on besides the file: the model modules' source, Python's and numpy's
    versions. Another checkout, release or numpy makes other objects, so it reads the file instead."""
    digest = hashlib.sha256(f"{sys.version_info[:2]} numpy {np.__version__}".encode())
    for module in sorted(_MODEL):
        digest.update(module.encode() + b"\0" + Path(import_module(module).__file__).read_bytes())
    return digest.digest()


def file_key(xodr: str | Path) -> bytes:
    from tavf_mapkit.pipeline.manifest import file_sha256  # the one sha256 of a file, as the manifest has it

    return bytes.fromhex(file_sha256(xodr))


def snapshot_file(xodr: str | Path, path: str | Path | None = None, sha256: str | None = None) -> OpenDriveMap:
    """Read ``xodr`` and save what was read as its snapshot (``path``, default beside it), atomically; the map.
    The snapshot is made from a fresh read, never from a map in use: it holds exactly what the reader returns,
    not the caches (``arrays``, ...) that use adds, nor a map changed in memory that the file does not say.
    ``sha256``: the file's (hex), when its writer took it as it wrote it (a region's: 500 MB not read again)."""
    from tavf_mapkit.fileutil import staged_file
    from tavf_mapkit.opendrive.reader import load_opendrive

    odr = load_opendrive(xodr)
    path = Path(path) if path is not None else snapshot_path(xodr)
    with staged_file(path) as temporary, open(temporary, "wb") as handle:
        handle.write(_MAGIC + code_key() + (bytes.fromhex(sha256) if sha256 is not None else file_key(xodr)))
        _ModelPickler(handle, protocol=5).dump(odr)
    return odr


def _model_fields(cls) -> tuple[str, ...] | None:
    """The fields of a model dataclass (roads, sections, lanes, marks, links: a map's objects), else None."""
    try:
        return _MODEL_FIELDS[cls]
    except KeyError:
        names = None
        if is_dataclass(cls) and cls.__name__ in _MODEL.get(cls.__module__, ()):
            names = tuple(field.name for field in fields(cls))
        _MODEL_FIELDS[cls] = names
        return names


_MODEL_FIELDS: dict[type, tuple[str, ...] | None] = {}


def _made(cls, values: tuple):
    """A model object from its field values, as its constructor leaves it. Pickle's own way costs more twice:
    slotted dataclasses' generated ``__setstate__`` asks ``dataclasses.fields`` again for every object (5 of 9 s
    of a Maribor snapshot's load), and setting a state through ``__dict__`` gives every road and lane section a
    dict of its own instead of the compact attribute storage its constructor gives (Maribor +28 % memory)."""
    names = _model_fields(cls)
    if names is None or len(values) != len(names):
        raise pickle.UnpicklingError(f"{getattr(cls, '__name__', cls)!s} is not a model class of {len(values)} fields")
    made = object.__new__(cls)
    for name, value in zip(names, values):
        object.__setattr__(made, name, value)
    return made


def _part(base: np.ndarray, start: int, shape: tuple):
    """A read-only view of ``shape`` into ``base`` from element ``start`` on (``_ModelPickler.reducer_override``)."""
    if not isinstance(base, np.ndarray) or not base.flags.c_contiguous:
        raise pickle.UnpicklingError("an array part needs a contiguous array to be part of")
    count = int(np.prod(shape, dtype=np.int64))
    if not 0 <= start <= start + count <= base.size:
        raise pickle.UnpicklingError(f"an array part [{start}, {start + count}) outside its {base.size} elements")
    part = base.reshape(-1)[start:start + count].reshape(shape)
    part.flags.writeable = False
    return part


class _ModelPickler(pickle.Pickler):
    def reducer_override(self, obj):
        """Model objects by their fields only: what a cache (``cached_property``) added is not saved. An array
        that is a part of a larger one (the reader keeps the reference lines' rows of many roads in one array,
        refline.RowPacker) is saved as that part, and the larger array once: a road's rows as arrays of their own
        cost Maribor's map 60 MB more."""
        cls = type(obj)
        if cls is np.ndarray:
            return _array_part(obj)
        try:  # asked of every tuple, list and dict too (a region: tens of millions): one lookup per object
            values = _FIELD_VALUES[cls]
        except KeyError:
            values = _FIELD_VALUES[cls] = _field_values(cls)
        if values is None:
            return NotImplemented
        return _made, (cls, values(obj))


def _field_values(cls):
    """A function of a model object giving its field values as a tuple (in ``_model_fields`` order); None for a
    class that is not a model class."""
    names = _model_fields(cls)
    if names is None:
        return None
    if len(names) < 2:  # attrgetter of one name gives the value, not a tuple (and of none is no getter)
        return lambda obj: tuple([getattr(obj, name) for name in names])
    return attrgetter(*names)


_FIELD_VALUES: dict = {}


def _array_part(array: np.ndarray):
    base = array.base
    if (type(base) is not np.ndarray or base.dtype != array.dtype or base.base is not None
            or not base.flags.c_contiguous or not array.flags.c_contiguous):
        return NotImplemented
    offset = array.ctypes.data - base.ctypes.data
    start, rest = divmod(offset, array.itemsize)
    if rest or not 0 <= start <= start + array.size <= base.size:
        return NotImplemented
    return _part, (base, start, array.shape)


class _ModelUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if name in _MODEL.get(module, ()) or (module, name) in _NUMPY:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"{module}.{name} is not part of a map snapshot")


def load_snapshot(path: str | Path, xodr: str | Path) -> OpenDriveMap | None:
    """The map saved in ``path`` if it is the snapshot of ``xodr`` as it is now, made by this code; else None."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            head = handle.read(len(_MAGIC) + 2 * _KEY_BYTES)
            if head != _MAGIC + code_key() + file_key(xodr):
                log.info("%s is not a snapshot of %s as it is now (or made by other code): reading the file",
                         path.name, Path(xodr).name)
                return None
            with collector_paused():  # millions of new objects, none of them garbage
                odr = _ModelUnpickler(handle).load()
    except FileNotFoundError:
        return None
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, TypeError, ValueError, IndexError) as error:
        log.warning("%s is damaged (%s): reading %s instead", path.name, error, Path(xodr).name)
        return None
    if not isinstance(odr, OpenDriveMap):
        log.warning("%s holds no map: reading %s instead", path.name, Path(xodr).name)
        return None
    return replace(odr, source=str(xodr))  # named as the reader names it: by the path it was asked for


def load_build_map(xodr: str | Path, snapshot: str | Path | None = None) -> OpenDriveMap:
    """``load_opendrive(xodr)``, from its snapshot when there is a valid one (``snapshot``, default beside it)."""
    from tavf_mapkit.opendrive.reader import load_opendrive

    odr = load_snapshot(snapshot if snapshot is not None else snapshot_path(xodr), xodr)
    return odr if odr is not None else load_opendrive(xodr)
