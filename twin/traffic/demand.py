"""Where traffic goes: a pool of vehicle routes and pedestrian walks, from a seed or from a routes file.

The runner keeps N vehicles and M pedestrians alive by starting new ones on the pool's routes, in order,
as others arrive; so the pool only has to be varied, not timed. From a seed it is made by the tools shipped in
the SUMO wheel: ``randomTrips.py`` (seeded random origin/destination pairs, validated) routed by ``duarouter``
-- the same two steps SUMO's own scenario wizards take. The same seed gives the same pool (the files differ only in their generation-time comments).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit.errors import InputError, StageError

# How many routes per requested object: enough variety that a vehicle rarely repeats its predecessor's route.
VEHICLE_POOL_FACTOR = 4
MIN_VEHICLE_POOL = 40
# Walkable edges are often few and disconnected (no sidewalks in the network): ask for many, keep what routes.
PEDESTRIAN_TRIALS_FACTOR = 10
MIN_PEDESTRIAN_TRIALS = 50
RANDOM_TRIPS_TIMEOUT_S = 300


@dataclass(frozen=True)
class Demand:
    """Routes as tuples of SUMO edge ids; ``source`` says where they came from."""

    vehicle_routes: tuple[tuple[str, ...], ...]
    walks: tuple[tuple[str, ...], ...]
    source: str


def sumo_home() -> Path:
    """SUMO_HOME of the eclipse-sumo wheel (its tools/ and bin/)."""
    import sumo

    return Path(sumo.SUMO_HOME)


def _tool_env() -> dict[str, str]:
    import pyproj

    env = dict(os.environ)
    env["SUMO_HOME"] = str(sumo_home())
    env["PATH"] = os.pathsep.join([str(sumo_home() / "bin"), str(Path(sys.executable).parent), env.get("PATH", "")])
    env.setdefault("PROJ_DATA", pyproj.datadir.get_data_dir())  # duarouter's PROJ would look elsewhere
    return env


def random_trips(net: Path, out: Path, seed: int, count: int, *, pedestrians: bool) -> Path:
    """Run randomTrips.py (+ duarouter) for ``count`` trips; return the routes file."""
    trips, routes = out.with_suffix(".trips.xml"), out
    command = [sys.executable, str(sumo_home() / "tools" / "randomTrips.py"), "-n", str(net),
               "-o", str(trips), "-r", str(routes), "--seed", str(seed), "-b", "0", "-e", str(count), "-p", "1",
               "--validate"]
    if pedestrians:
        command += ["--pedestrians", "--prefix", "p", "--max-distance", "2000"]
    else:
        command += ["--vclass", "passenger", "--prefix", "v", "--min-distance", "150", "--fringe-factor", "2"]
    try:
        result = subprocess.run(command, capture_output=True, text=True, env=_tool_env(),
                                timeout=RANDOM_TRIPS_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        raise StageError(f"randomTrips.py did not finish within {RANDOM_TRIPS_TIMEOUT_S} s", file=str(net)) from None
    if result.returncode != 0 or not routes.is_file():
        last = (result.stderr.strip().splitlines() or ["no output"])[-1]
        raise StageError(f"randomTrips.py failed (exit {result.returncode}): {last}", file=str(net))
    return routes


def generate_demand(net: str | Path, seed: int, vehicles: int, pedestrians: int,
                    work_dir: str | Path | None = None) -> Demand:
    """A seeded pool of routes for ``vehicles`` cars and walks for ``pedestrians`` people."""
    net = Path(net)
    with tempfile.TemporaryDirectory(prefix="twin-demand-") as scratch:
        folder = Path(work_dir) if work_dir is not None else Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        routes: tuple[tuple[str, ...], ...] = ()
        walks: tuple[tuple[str, ...], ...] = ()
        if vehicles > 0:
            count = max(MIN_VEHICLE_POOL, VEHICLE_POOL_FACTOR * vehicles)
            routes = read_demand(random_trips(net, folder / "vehicles.rou.xml", seed, count,
                                              pedestrians=False)).vehicle_routes
            if not routes:
                raise InputError("no routable trips for passenger cars in the network", file=str(net))
        if pedestrians > 0:
            count = max(MIN_PEDESTRIAN_TRIALS, PEDESTRIAN_TRIALS_FACTOR * pedestrians)
            # a different stream than the vehicles', so adding people does not change the cars' routes
            walks = read_demand(random_trips(net, folder / "pedestrians.rou.xml", seed + 7919, count,
                                             pedestrians=True)).walks
            if not walks:
                raise InputError("no walkable routes for pedestrians in the network (no lanes allow them; "
                                 "build with --profile full for sidewalks)", file=str(net))
    return Demand(routes, walks, f"randomTrips seed={seed}")


def read_demand(path: str | Path) -> Demand:
    """Routes (``<route edges>``, inside ``<vehicle>`` or standalone) and walks (``<walk edges>``) of a file."""
    from tavf_mapkit.xmlsafe import iterparse_safe, read_xml_source

    name = str(path)
    routes: list[tuple[str, ...]] = []
    walks: list[tuple[str, ...]] = []
    unrouted = None
    for _event, element in iterparse_safe(read_xml_source(path), events=("end",)):
        tag = element.tag
        if tag == "route" and (element.getparent() is None or element.getparent().tag != "person"):
            edges = tuple((element.get("edges") or "").split())
            if not edges:
                raise InputError("a <route> without edges", file=name, line=element.sourceline)
            routes.append(edges)
        elif tag == "walk":
            edges = tuple((element.get("edges") or "").split())
            if edges:
                walks.append(edges)
            elif unrouted is None:
                unrouted = element
        elif tag in ("trip", "flow", "personTrip") and element.find("route") is None and unrouted is None:
            unrouted = element
        if tag in ("vehicle", "person", "routes"):
            element.clear(keep_tail=True)
    if unrouted is not None and not routes and not walks:
        raise InputError(f"<{unrouted.tag}> has no routed edges; route the file with duarouter first",
                         file=name, line=unrouted.sourceline)
    if not routes and not walks:
        raise InputError("no <route edges=...> or <walk edges=...> in the routes file", file=name)
    return Demand(tuple(routes), tuple(walks), name)
