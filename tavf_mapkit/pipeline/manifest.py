"""manifest.json: what went into a build and what came out, precise enough to decide what to rebuild.

Also the helpers that make it precise: sha256 of files and folders, a stage fingerprint over its input
hashes and options, and the versions of the tools and Python packages that did the work.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
from importlib import metadata
from pathlib import Path

MANIFEST_NAME = "manifest.json"
MANIFEST_VERSION = 1
OSM_ATTRIBUTION = "(c) OpenStreetMap contributors, ODbL 1.0"
PACKAGES = ("tavf-mapkit", "osmium", "eclipse-sumo", "sumolib", "lxml", "pyproj", "shapely", "numpy", "click")


#: files up to this size are hashed from one read (a region's mesh folder holds ~100k small tiles, where
#: ``file_digest``'s buffer per file costs more than the hashing); larger ones in blocks, in bounded memory
WHOLE_READ_BYTES = 16 << 20


def file_sha256(path: str | Path, size: int | None = None) -> str:
    """sha256 (hex) of a file; ``size``: its size, if known (saves a ``stat``)."""
    with open(path, "rb") as handle:
        if (size if size is not None else os.fstat(handle.fileno()).st_size) <= WHOLE_READ_BYTES:
            return hashlib.sha256(handle.read()).hexdigest()
        return hashlib.file_digest(handle, "sha256").hexdigest()


def _files_below(folder: Path) -> list[tuple[tuple[str, ...], str, int]]:
    """(relative parts, path, bytes) of every file below ``folder``, in the order of sorted ``Path`` objects (by
    parts). One ``os.scandir`` walk: a mesh folder of a region holds ~100k files, where ``Path.rglob`` and a
    ``stat`` per path cost more than hashing them."""
    found = []
    pending = [((), os.fspath(folder))]
    while pending:
        parts, directory = pending.pop()
        with os.scandir(directory) as entries:
            for entry in entries:
                if entry.is_dir(follow_symlinks=False):
                    pending.append(((*parts, entry.name), entry.path))
                elif entry.is_file():
                    found.append(((*parts, entry.name), entry.path, entry.stat().st_size))
    found.sort(key=lambda item: item[0])
    return found


def path_sha256_and_bytes(path: str | Path) -> tuple[str, int]:
    """(sha256, bytes) of a file, or of a folder: the hash of its sorted (relative path, file hash) list and the
    sum of its files' sizes, from one walk."""
    path = Path(path)
    if not path.is_dir():
        return file_sha256(path), path.stat().st_size
    digest, total = hashlib.sha256(), 0
    for parts, item, size in _files_below(path):
        digest.update(f"{'/'.join(parts)}\0{file_sha256(item, size)}\n".encode())
        total += size
    return digest.hexdigest(), total


def path_sha256(path: str | Path) -> str:
    """sha256 of a file, or of a folder as the hash of its sorted (relative path, file hash) list."""
    return path_sha256_and_bytes(path)[0]


def path_bytes(path: str | Path) -> int:
    path = Path(path)
    if path.is_dir():
        return sum(size for _, _, size in _files_below(path))
    return path.stat().st_size


def canonical(value) -> object:
    """JSON-ready value: Paths become ``{"path", "sha256"}`` so a changed file changes a fingerprint."""
    if isinstance(value, dict):
        return {str(key): canonical(item) for key, item in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [canonical(item) for item in value]
    if isinstance(value, Path):
        return {"path": str(value), "sha256": path_sha256(value) if value.exists() else None}
    return value


def fingerprint(stage: str, version: str, options: dict, inputs: dict[str, str]) -> str:
    """sha256 over what determines a stage's result: its name, code version, options and input hashes."""
    text = json.dumps({"stage": stage, "version": version, "options": options, "inputs": inputs},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def package_versions() -> dict[str, str | None]:
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def tool_versions(netconvert: str | None) -> dict:
    return {
        "netconvert": netconvert,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "packages": package_versions(),
    }


def read_manifest(folder: Path) -> dict | None:
    """The manifest of an existing build, or None if there is none or it cannot be trusted."""
    path = Path(folder) / MANIFEST_NAME
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("manifest_version") != MANIFEST_VERSION:
        return None
    return data


def write_manifest(folder: Path, manifest: dict) -> Path:
    path = Path(folder) / MANIFEST_NAME
    text = json.dumps(manifest, indent=2, sort_keys=False) + "\n"
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    return path


def stage_record(manifest: dict | None, name: str) -> dict | None:
    """The entry of stage ``name`` in a manifest, if it ran or was reused there."""
    if not manifest:
        return None
    for record in manifest.get("stages", []):
        if record.get("name") == name and record.get("status") in ("ran", "unchanged"):
            return record
    return None
