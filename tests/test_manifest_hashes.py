"""manifest's file and folder hashes: a folder's sha256 is that of its sorted (relative path, file sha256) list,
in the order of sorted ``Path`` objects (by parts, not by string: 'a/b' before 'a-c'), whatever way it is walked."""

from __future__ import annotations

import hashlib
from pathlib import Path

from tavf_mapkit.pipeline import manifest
from tavf_mapkit.pipeline.manifest import file_sha256, path_bytes, path_sha256, path_sha256_and_bytes


def _folder(tmp_path: Path) -> Path:
    folder = tmp_path / "out"
    files = {"b": b"bee", "a-c": b"", "a/b": b"x" * 5000, "a/x/y.npz": bytes(range(256)) * 9, "a.txt": b"t"}
    for relative, data in files.items():
        (folder / relative).parent.mkdir(parents=True, exist_ok=True)
        (folder / relative).write_bytes(data)
    (folder / "empty_dir").mkdir()
    return folder


def _by_rglob(folder: Path) -> str:
    """The definition, written the plain way: sorted Path objects from rglob."""
    digest = hashlib.sha256()
    for item in sorted(p for p in folder.rglob("*") if p.is_file()):
        digest.update(f"{item.relative_to(folder).as_posix()}\0{hashlib.sha256(item.read_bytes()).hexdigest()}\n"
                      .encode())
    return digest.hexdigest()


def test_folder_hash_is_the_sorted_path_definition(tmp_path):
    folder = _folder(tmp_path)
    assert [parts for parts, _, _ in manifest._files_below(folder)] == [
        ("a", "b"), ("a", "x", "y.npz"), ("a-c",), ("a.txt",), ("b",)]
    assert path_sha256(folder) == _by_rglob(folder)
    assert path_sha256_and_bytes(folder) == (_by_rglob(folder), 3 + 0 + 5000 + 256 * 9 + 1)
    assert path_bytes(folder) == 3 + 5000 + 256 * 9 + 1


def test_large_files_hash_in_blocks_the_same(tmp_path, monkeypatch):
    big = tmp_path / "big.bin"
    big.write_bytes(bytes(range(256)) * 4099)
    whole = file_sha256(big)
    monkeypatch.setattr(manifest, "WHOLE_READ_BYTES", 1000)  # now read in blocks by file_digest
    assert file_sha256(big) == whole == hashlib.sha256(big.read_bytes()).hexdigest()
    assert path_sha256_and_bytes(big) == (whole, 256 * 4099)
