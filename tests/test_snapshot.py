"""A build's map snapshot (NAME.odrmap, tavf_mapkit/opendrive/snapshot.py): it gives exactly what the reader
gives for the same file, is used only for that file and by the code that made it, and cannot run code."""

from __future__ import annotations

import logging
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.snapshot import (
    _MAGIC,
    code_key,
    file_key,
    load_build_map,
    load_snapshot,
    snapshot_file,
    snapshot_path,
)
from tavf_mapkit.opendrive.summary import summarise
from tavf_mapkit.opendrive.writer import write_opendrive

# files with what netconvert never writes: objects with outlines and repeats, signals and references, lane
# heights, shapes, several controllers (CARLA, the surveyed A9, CommonRoad's converter)
ZOO_FILES = ["carla_Town04.xodr", "real_DE_A9_providentia_muenchen.xodr", "commonroad_DEU_Muehlhausen.xodr",
             "esmini_e6mini-lht_LHT.xodr"]


def _same_map(snapshot_map, read_map, tmp_path: Path) -> None:
    """The two maps write the same file, summarise alike and put every lane border in the same place."""
    write_opendrive(snapshot_map, tmp_path / "from-snapshot.xodr")
    write_opendrive(read_map, tmp_path / "from-reader.xodr")
    assert (tmp_path / "from-snapshot.xodr").read_bytes() == (tmp_path / "from-reader.xodr").read_bytes()
    assert summarise(snapshot_map) == summarise(read_map)
    assert snapshot_map.source == read_map.source
    assert snapshot_map.warnings == read_map.warnings
    ours, theirs = snapshot_map.arrays, read_map.arrays
    s = np.linspace(0.0, 1.0, 7)
    for road_index in range(0, len(read_map.roads), max(1, len(read_map.roads) // 40)):
        length = read_map.roads[road_index].length
        a = ours.reference(np.full(len(s), road_index), s * length)
        b = theirs.reference(np.full(len(s), road_index), s * length)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("name", ZOO_FILES)
def test_snapshot_is_what_the_reader_reads(shared, tmp_path, name):
    xodr = tmp_path / name
    shutil.copyfile(shared("zoo", "xodr", name), xodr)
    made = snapshot_file(xodr)
    assert snapshot_path(xodr).is_file()
    loaded = load_snapshot(snapshot_path(xodr), xodr)
    assert loaded is not None
    read = load_opendrive(xodr)
    _same_map(loaded, read, tmp_path)
    _same_map(made, read, tmp_path)


def test_build_writes_a_valid_snapshot_the_twin_reads(sample_build_dir, tmp_path):
    import json

    manifest = json.loads((sample_build_dir / "manifest.json").read_text())
    assert manifest["artifacts"]["odrmap"]["path"] == "sample.odrmap"
    xodr = sample_build_dir / "sample.xodr"
    loaded = load_snapshot(sample_build_dir / "sample.odrmap", xodr)
    assert loaded is not None
    _same_map(loaded, load_opendrive(xodr), tmp_path)


def test_a_changed_file_is_read_again(shared, tmp_path, caplog):
    xodr = tmp_path / "town.xodr"
    shutil.copyfile(shared("zoo", "xodr", "carla_Town04.xodr"), xodr)
    snapshot_file(xodr)
    with open(xodr, "ab") as handle:
        handle.write(b"<!-- edited after the build -->\n")
    with caplog.at_level(logging.INFO, logger="tavf_mapkit.opendrive.snapshot"):
        assert load_snapshot(snapshot_path(xodr), xodr) is None
    assert "town.odrmap is not a snapshot of town.xodr as it is now" in caplog.text
    assert len(load_build_map(xodr).roads) == len(load_opendrive(xodr).roads)


class _RunsCode:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def test_a_snapshot_cannot_run_code(shared, tmp_path, caplog):
    xodr = tmp_path / "town.xodr"
    shutil.copyfile(shared("zoo", "xodr", "carla_Town04.xodr"), xodr)
    marker = tmp_path / "ran"
    # a valid head for this very file and code, then a pickle that would run a shell command
    snapshot_path(xodr).write_bytes(_MAGIC + code_key() + file_key(xodr) + pickle.dumps(_RunsCode(marker)))
    with caplog.at_level(logging.WARNING, logger="tavf_mapkit.opendrive.snapshot"):
        odr = load_build_map(xodr)
    assert not marker.exists()
    assert "town.odrmap is damaged (posix.system is not part of a map snapshot)" in caplog.text
    assert len(odr.roads) == len(load_opendrive(xodr).roads)  # read from the file instead


def test_a_truncated_snapshot_is_ignored(shared, tmp_path, caplog):
    xodr = tmp_path / "town.xodr"
    shutil.copyfile(shared("zoo", "xodr", "carla_Town04.xodr"), xodr)
    snapshot_file(xodr)
    data = snapshot_path(xodr).read_bytes()
    snapshot_path(xodr).write_bytes(data[: len(data) // 2])
    with caplog.at_level(logging.WARNING, logger="tavf_mapkit.opendrive.snapshot"):
        assert load_snapshot(snapshot_path(xodr), xodr) is None
    assert "town.odrmap is damaged" in caplog.text


def test_a_snapshot_of_other_code_is_not_used(shared, tmp_path):
    xodr = tmp_path / "town.xodr"
    shutil.copyfile(shared("zoo", "xodr", "carla_Town04.xodr"), xodr)
    snapshot_file(xodr)
    data = bytearray(snapshot_path(xodr).read_bytes())
    data[len(_MAGIC)] ^= 0xFF  # another model's source, numpy or Python
    snapshot_path(xodr).write_bytes(bytes(data))
    assert load_snapshot(snapshot_path(xodr), xodr) is None


def test_rows_shared_by_the_reader_stay_shared(shared, tmp_path):
    xodr = tmp_path / "town.xodr"
    shutil.copyfile(shared("zoo", "xodr", "carla_Town04.xodr"), xodr)
    snapshot_file(xodr)

    def bases(odr) -> int:
        return len({id(road.reference_line.narrow.base) for road in odr.roads if len(road.reference_line)})

    read, loaded = load_opendrive(xodr), load_snapshot(snapshot_path(xodr), xodr)
    assert bases(read) == bases(loaded) < len(read.roads) / 10


class _PartOutside:
    def __reduce__(self):
        from tavf_mapkit.opendrive.snapshot import _part

        return _part, (np.zeros(3), 2, (5,))


def test_an_array_part_outside_its_array_is_refused(shared, tmp_path, caplog):
    xodr = tmp_path / "town.xodr"
    shutil.copyfile(shared("zoo", "xodr", "carla_Town04.xodr"), xodr)
    snapshot_path(xodr).write_bytes(_MAGIC + code_key() + file_key(xodr) + pickle.dumps(_PartOutside()))
    with caplog.at_level(logging.WARNING, logger="tavf_mapkit.opendrive.snapshot"):
        assert load_snapshot(snapshot_path(xodr), xodr) is None
    assert "an array part [2, 7) outside its 3 elements" in caplog.text
