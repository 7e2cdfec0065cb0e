"""Atomic outputs (tavf_mapkit/fileutil.py): the one staged-folder helper behind build folders, mesh folders,
the collision world and twin drive outputs, and the staged file behind single-file writes."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from tavf_mapkit.errors import InputError
from tavf_mapkit.fileutil import StagedFolder, Terminated, staged_file, staged_folder


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def test_a_folder_replaces_the_previous_one_whole(tmp_path):
    target = tmp_path / "out"
    with staged_folder(target, marker="done") as staging:
        (staging / "done").write_text("1")
        (staging / "a.txt").write_text("first")
        assert not target.exists()  # nothing at the target until the block ends
    old = os.umask(0o022)
    try:
        with staged_folder(target, marker="done") as staging:
            (staging / "done").write_text("2")
            assert tree(target) == {"a.txt": b"first", "done": b"1"}  # the previous one, untouched meanwhile
    finally:
        os.umask(old)
    assert tree(target) == {"done": b"2"} and leftovers(tmp_path) == []
    assert target.stat().st_mode & 0o777 == 0o755  # a folder like mkdir makes, not mkdtemp's private one


@pytest.mark.parametrize("failure", [RuntimeError("stage failed"), KeyboardInterrupt()])
def test_a_failure_leaves_the_previous_folder_as_it_was(tmp_path, failure):
    target = tmp_path / "out"
    target.mkdir()
    (target / "done").write_text("previous")
    with pytest.raises(type(failure)), staged_folder(target, marker="done") as staging:
        (staging / "done").write_text("half")
        raise failure
    assert tree(target) == {"done": b"previous"} and leftovers(tmp_path) == []


def test_sigterm_while_staged_cleans_up_like_ctrl_c_and_restores_the_handler(tmp_path):
    """A command killed with SIGTERM (a scheduler, `timeout`, systemd) leaves the previous folder and nothing
    else; outside a staged folder SIGTERM is the caller's again."""
    target = tmp_path / "out"
    target.mkdir()
    (target / "done").write_text("previous")
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated), staged_folder(target, marker="done") as staging:
        (staging / "done").write_text("half")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises at the next bytecode; never reached
    assert tree(target) == {"done": b"previous"} and leftovers(tmp_path) == []
    assert signal.getsignal(signal.SIGTERM) is before
    with staged_folder(target, marker="done") as staging:
        (staging / "done").write_text("new")
    assert signal.getsignal(signal.SIGTERM) is before and tree(target) == {"done": b"new"}


def test_folders_that_are_not_ours_are_refused_in_one_line(tmp_path):
    precious = tmp_path / "thesis"
    precious.mkdir()
    (precious / "thesis.tex").write_text("years of work")
    with pytest.raises(InputError) as refused:
        StagedFolder(precious, marker="mesh.json", refusal="holds no mesh.json: refusing to replace it").open()
    assert str(refused.value) == f"{precious.absolute()}: holds no mesh.json: refusing to replace it"
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="file: exists and is not a folder$"):
        StagedFolder(tmp_path / "file").open()
    with pytest.raises(InputError, match="file: is not a folder$"):
        StagedFolder(tmp_path / "file" / "below" / "out").open()
    assert (precious / "thesis.tex").read_text() == "years of work" and leftovers(tmp_path) == []


def test_the_target_never_disappears_while_folders_are_exchanged(tmp_path):
    """Readers of the target see the old folder or the new one, never none (renameat2 RENAME_EXCHANGE)."""
    target = tmp_path / "out"
    with staged_folder(target) as staging:
        (staging / "marker").write_text("0")
    missing, stop = [], threading.Event()

    def read() -> None:
        while not stop.is_set():
            if not (target / "marker").is_file():
                missing.append(1)

    reader = threading.Thread(target=read)
    reader.start()
    try:
        for k in range(1, 101):
            with staged_folder(target) as staging:
                (staging / "marker").write_text(str(k))
    finally:
        stop.set()
        reader.join()
    assert not missing and (target / "marker").read_text() == "100" and leftovers(tmp_path) == []


def test_recover_clears_what_a_killed_writer_left(tmp_path):
    target = tmp_path / "out"
    # killed between the two renames of the fallback swap: the previous folder waits beside the target
    aside = tmp_path / ".out.staging-abc-old"
    aside.mkdir()
    (aside / "manifest.json").write_text("{}")
    unfinished = tmp_path / ".out.staging-def"
    unfinished.mkdir()
    (unfinished / "half").write_text("")
    done = StagedFolder(target, marker="manifest.json", what="the build folder").recover()
    assert done == ["put the previous build folder back from .out.staging-abc-old",
                    "removed its unfinished staging folder .out.staging-def"]
    assert tree(target) == {"manifest.json": b"{}"} and leftovers(tmp_path) == []


def test_a_staged_file_is_complete_or_absent(tmp_path):
    target = tmp_path / "map.osm.pbf"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError), staged_file(target, suffix=".osm.pbf") as partial:
        assert partial.parent == tmp_path and partial.name.endswith(".osm.pbf") and partial.name.startswith(".")
        partial.write_bytes(b"half")
        raise RuntimeError("writer failed")
    assert target.read_bytes() == b"old" and leftovers(tmp_path) == []
    old = os.umask(0o022)
    try:
        with staged_file(target) as partial:
            partial.write_bytes(b"new")
    finally:
        os.umask(old)
    assert target.read_bytes() == b"new" and target.stat().st_mode & 0o777 == 0o644 and leftovers(tmp_path) == []
    with pytest.raises(InputError, match="output folder does not exist"), staged_file(tmp_path / "no" / "x"):
        pass
