"""Random-route plans kept between drives: a region's route selection is computed once per map and code.

Choosing where random routes may go (``RandomRoutes``: every lane's line measured, every step between lanes,
the components) evaluates every lane of the map: on a 59,133-road region most of a drive's start. What the walk
needs afterwards is small -- the chosen lanes, their follow, lane-change, turnaround and exit tables and their
lengths -- so it is saved with the lane graph's topology, and a later drive on the same map with the same code
reads both back: no walk over the map's lanes and links, and the lanes' lines are built only as the cars reach
them (``LaneLines``), the map's lines are never all evaluated.

A plan is used only for the map it was made from (its sha256, size and modification time), by the code that made
it (a digest of the modules it depends on, Python's and numpy's versions) and with the same
parameters; its lane keys are checked against the lane graph. Anything else computes the plan again: the walk
is the same either way, to the bit (tests/test_route_cache.py). The plans live in ``$MAPKIT_CACHE/routes``
(default ``$XDG_CACHE_HOME/tavf-mapkit``, else ``~/.cache/tavf-mapkit``); ``MAPKIT_CACHE=off`` keeps none.
"""

from __future__ import annotations

import hashlib
import logging
import os
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

PLAN_VERSION = 1


def cache_folder() -> Path | None:
    """Where plans are kept; None when ``MAPKIT_CACHE=off``."""
    configured = os.environ.get("MAPKIT_CACHE")
    if configured is not None:
        return None if configured.strip().lower() in ("", "off", "0", "no") else Path(configured) / "routes"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "tavf-mapkit" / "routes"


#: the code a plan depends on, whole packages (a plan is never stale, and a dependency added later is covered):
#: the twin, the map model and its evaluation, the lane graph, the mesh package (route selection measures bends
#: with its swept-path code) and tavf_mapkit's top-level modules. Not the export, pipeline, world or view code,
#: which other work changes often and no plan depends on
_PLAN_CODE = ("twin", "tavf_mapkit/opendrive", "tavf_mapkit/lanegraph", "tavf_mapkit/mesh", "tavf_mapkit/*.py")
#: nor the OpenDRIVE file's reading and writing: the map a drive gets is that of the build's snapshot, whose
#: validity does not depend on the reader either (``opendrive.snapshot.code_key``: the model's modules, which
#: are part of the digest); a new reader comes with a new build
_FILE_FORMAT = ("tavf_mapkit/opendrive/reader.py", "tavf_mapkit/opendrive/planview_scan.py",
                "tavf_mapkit/opendrive/writer.py")


@lru_cache(maxsize=1)
def code_digest() -> bytes:
    """sha256 over the modules a plan depends on (``_PLAN_CODE``) and the Python and numpy versions: a change
    of that code may change a plan, so any change makes a new one."""
    import tavf_mapkit

    root = Path(tavf_mapkit.__file__).parent.parent
    files = set()
    for part in _PLAN_CODE:
        files.update(root.glob(part) if part.endswith(".py") else (root / part).rglob("*.py"))
    files.difference_update(root / part for part in _FILE_FORMAT)
    digest = hashlib.sha256(f"{sys.version_info[:3]} numpy {np.__version__} plan {PLAN_VERSION}".encode())
    for path in sorted(files):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.digest()


def plan_key(xodr: Path, map_sha256: str, parameters: dict) -> str:
    """The name of the plan for this map file, code and parameters."""
    stat = Path(xodr).stat()
    digest = hashlib.sha256(code_digest())
    digest.update(f"{map_sha256} {stat.st_size} {stat.st_mtime_ns} {sorted(parameters.items())}".encode())
    return digest.hexdigest()[:40]


def plan_path(xodr: Path, map_sha256: str, max_cut: float, lane_change_probability: float, step: float,
              lane_types) -> Path | None:
    """Where the plan for this map, code and parameters is kept; None when plans are not kept."""
    folder = cache_folder()
    if folder is None:
        return None
    parameters = {"max_cut": float(max_cut), "lane_change_probability": float(lane_change_probability),
                  "step": float(step), "lane_types": sorted(lane_types)}
    return folder / f"{plan_key(xodr, map_sha256, parameters)}.npz"


def graph_arrays(graph) -> dict[str, np.ndarray]:
    """The lane graph as a plan keeps it (its keys, rows, directions and edges; no lane table)."""
    edges = graph._topology
    return {"graph_keys": graph.key_array, "graph_rows": graph._row,
            "graph_ahead": np.asarray(graph._ahead, dtype=bool), "graph_indptr": edges.indptr,
            "graph_target": edges.target, "graph_kind": edges.kind, "graph_weight": edges.weight}


def kept_lane_graph(odr, xodr: Path, map_sha256: str, step: float = 1.0, lane_types=("driving",)):
    """The lane graph of a kept plan (what ``LaneGraph.from_opendrive(odr, lane_types, step=step)`` gives, without
    walking the map), None without one."""
    from tavf_mapkit.lanegraph import LaneGraph, LaneKey
    from tavf_mapkit.lanegraph.edges import EdgeArrays
    from twin.planning.drivable import MAX_CUT

    path = plan_path(xodr, map_sha256, MAX_CUT, 0.2, step, lane_types)
    plan = read_plan(path) if path is not None else None
    if plan is None or "graph_keys" not in plan:
        return None
    keys = [LaneKey(*key) for key in plan["graph_keys"].tolist()]
    edges = EdgeArrays(len(keys), plan["graph_indptr"], plan["graph_target"], plan["graph_kind"],
                       plan["graph_weight"])
    graph = LaneGraph(odr, keys, plan["graph_rows"], plan["graph_ahead"], edges, None, step, frozenset(lane_types))
    return graph if str(plan["graph"]) == keys_digest(graph) else None


def keys_digest(graph) -> str:
    """sha256 of the lane graph's keys in node order (plans name lanes by node number)."""
    return hashlib.sha256(graph.key_array.tobytes()).hexdigest()


def read_plan(path: Path) -> dict | None:
    """The arrays saved in ``path``; None without a readable plan there."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            return {name: stored[name] for name in stored.files}
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, EOFError) as error:
        log.warning("route plan %s is unreadable (%s): computing it again", path.name, error)
        return None


def load_plan(path: Path, graph) -> dict | None:
    """The plan saved in ``path`` if it fits ``graph``; None otherwise (no file, damaged, another graph)."""
    plan = read_plan(path)
    if plan is None:
        return None
    if str(plan.get("graph", "")) != keys_digest(graph):
        log.info("route plan %s is for another lane graph: computing it again", path.name)
        return None
    return plan


def save_plan(path: Path, plan: dict) -> None:
    """Write ``plan`` (name -> array) atomically; a cache that cannot be written is only logged."""
    from tavf_mapkit.fileutil import staged_file

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with staged_file(path, suffix=".npz") as temporary:
            np.savez(temporary, **plan)
    except Exception as error:  # noqa: BLE001 -- a cache never fails a drive
        log.warning("route plan not kept (%s: %s)", type(error).__name__, error)
