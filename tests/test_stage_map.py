"""The build's map kept from the mesh stage for the check stage (pipeline/builtin/stage_map.py): one load for both
when the file is small, per build and per file, never for a large file, let go by its last reader."""

from __future__ import annotations

import gc
import os
import shutil
import weakref

from tavf_mapkit.pipeline.builtin import stage_map as kept_maps
from tavf_mapkit.pipeline.config import load_pipeline
from tavf_mapkit.pipeline.context import BuildContext


def context_of(xodr) -> BuildContext:
    return BuildContext(name="t", folder=xodr.parent, input_path=xodr, input_kind="opendrive",
                        config=load_pipeline(None), artifacts={"xodr": xodr})


def test_a_small_map_is_loaded_once_per_build_and_file(shared, tmp_path, monkeypatch):
    xodr = tmp_path / "map.xodr"
    shutil.copy(shared("xodr", "esmini", "fabriksgatan.xodr"), xodr)
    build = context_of(xodr)
    odr = kept_maps.stage_map(build)
    assert kept_maps.stage_map(build) is odr                     # the check stage's read: the same map
    assert kept_maps.stage_map(context_of(xodr)) is not odr      # another build loads its own
    assert kept_maps.take_kept_map(build) is odr
    assert kept_maps.take_kept_map(build) is None                 # its last reader took it: no longer held
    kept_maps.stage_map(build)
    stat = xodr.stat()
    os.utime(xodr, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))  # the file was written again
    assert kept_maps.take_kept_map(build) is None
    monkeypatch.setattr(kept_maps, "KEEP_BYTES", stat.st_size - 1)  # a larger file than the limit
    kept_maps.stage_map(build)
    assert kept_maps.take_kept_map(build) is None


def test_the_kept_map_goes_with_its_build(shared, tmp_path):
    xodr = tmp_path / "map.xodr"
    shutil.copy(shared("xodr", "esmini", "fabriksgatan.xodr"), xodr)
    build = context_of(xodr)
    gone = weakref.finalize(kept_maps.stage_map(build), lambda: None)  # a build that failed before its check
    gc.collect()
    assert gone.alive                                                  # held by its build ...
    del build
    gc.collect()
    assert not gone.alive                                              # ... and by nothing else
