"""SUMO in the twin's process: traffic on the build's own network, stepped with the twin's fixed step.

``SumoTraffic`` starts SUMO through ``libsumo`` (in-process, no socket; ``traci`` only if libsumo is missing),
keeps N vehicles and M pedestrians alive by starting new ones from the demand pool as others arrive, removes
vehicles that start to teleport (SUMO's answer to a jam -- in a 3D world a car must not vanish and reappear
elsewhere), moves the ego to its twin pose so traffic reacts to it, and hands out one ``TrafficSnapshot`` per
step in the OpenDRIVE local frame.

libsumo is one simulation per process: a second ``SumoTraffic`` while one is open is refused.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

import numpy as np

from tavf_mapkit.errors import InputError, StageError
from twin.traffic.demand import Demand, generate_demand, read_demand, sumo_home
from twin.traffic.frames import NetFrame

try:  # in-process SUMO; traci speaks the same API over a socket to a sumo child process
    import libsumo as sumo_api

    USING_LIBSUMO = True
except ImportError:  # pragma: no cover - the eclipse-sumo wheels ship libsumo on every platform we run on
    import traci as sumo_api

    USING_LIBSUMO = False

from traci import constants as tc

log = logging.getLogger(__name__)

EGO_ID = "ego"
EGO_TYPE = "twin_ego"
VEHICLE_PREFIX = "t"
PERSON_PREFIX = "p"
_SUBSCRIBED = (tc.VAR_POSITION3D, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_TYPE, tc.VAR_ROAD_ID, tc.VAR_LANE_ID,
               tc.VAR_LANEPOSITION)
# moveToXY looks for lanes this far from the ego; SUMO's default (100 m) makes every step search hundreds of
# lanes, while the twin's car is on or next to a lane
MATCH_THRESHOLD_M = 10.0
_RUNNING = threading.Lock()  # held while a SUMO simulation is open in this process


@dataclass(frozen=True)
class TrafficConfig:
    vehicles: int = 0
    pedestrians: int = 0
    seed: int = 0
    step_s: float = 0.05
    demand: Path | None = None  # a routes file instead of seeded random trips
    time_to_teleport_s: float = 60.0  # SUMO's jam detector; such vehicles are removed, then replaced
    ego_length_m: float = 4.97
    ego_width_m: float = 1.96
    ego_height_m: float = 1.45
    junction_placement: bool = True  # cars in junctions follow the OpenDRIVE connecting lanes (lanemap.py)

    def check(self) -> None:
        if self.vehicles < 0 or self.pedestrians < 0:
            raise InputError("--traffic and --pedestrians must be >= 0")
        if not (math.isfinite(self.step_s) and 0.001 <= self.step_s <= 1.0):
            raise InputError(f"step {self.step_s} s is outside 0.001..1 s")


@dataclass(frozen=True, eq=False)
class Actors:
    """SUMO vehicles and persons of one step; positions are SUMO's reference points (the front bumper).

    All arrays have one entry per actor, in SUMO's order (insertion order), in the OpenDRIVE local frame.
    """

    ids: tuple[str, ...]
    is_person: np.ndarray
    type_id: tuple[str, ...]
    road_id: tuple[str, ...]
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    yaw: np.ndarray  # rad, ccw from local +x
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    placed: np.ndarray  # True where a junction position was moved onto the OpenDRIVE connecting lane
    sumo_x: np.ndarray  # SUMO's own position, transformed into the local frame only
    sumo_y: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def centre(self) -> np.ndarray:
        """(n, 3) box centres: half a length behind the front bumper, half a height above the ground."""
        half = 0.5 * self.length
        return np.column_stack([self.x - half * np.cos(self.yaw), self.y - half * np.sin(self.yaw),
                                self.z + 0.5 * self.height])

    def select(self, mask: np.ndarray) -> Actors:
        keep = np.flatnonzero(mask)
        def pick(seq):
            return tuple(seq[i] for i in keep)

        return Actors(pick(self.ids), self.is_person[keep], pick(self.type_id), pick(self.road_id),
                      self.x[keep], self.y[keep], self.z[keep], self.yaw[keep], self.speed[keep],
                      self.length[keep], self.width[keep], self.height[keep], self.placed[keep],
                      self.sumo_x[keep], self.sumo_y[keep])


@dataclass(frozen=True, eq=False)
class SignalLinks:
    """Every controlled link of every traffic light: where its stop line is and which lanes it joins."""

    tls_id: tuple[str, ...]
    link_index: np.ndarray
    in_lane: tuple[str, ...]
    out_lane: tuple[str, ...]
    stop_x: np.ndarray  # local frame: the end of the incoming lane
    stop_y: np.ndarray
    stop_yaw: np.ndarray  # direction of travel at the stop line
    out_x: np.ndarray  # the start of the outgoing lane (tells the turn apart)
    out_y: np.ndarray

    def __len__(self) -> int:
        return len(self.tls_id)


@dataclass(frozen=True, eq=False)
class TrafficSnapshot:
    step: int
    time: float
    actors: Actors
    signal_state: np.ndarray  # one SUMO state letter per SignalLinks row: r y g G s o O u


@dataclass
class TrafficStats:
    inserted_vehicles: int = 0
    inserted_persons: int = 0
    arrived_vehicles: int = 0
    arrived_persons: int = 0
    teleports_removed: int = 0
    ego_move_errors: int = 0
    last_ego_error: str = ""
    extra: dict = field(default_factory=dict)


def sumo_binary() -> str:
    return str(sumo_home() / "bin" / "sumo")


def crossing_edges(net_path: Path) -> frozenset[str]:
    """Ids of the network's pedestrian crossings (``<edge function="crossing">``)."""
    from tavf_mapkit.sumonet import read_net_bytes
    from tavf_mapkit.xmlsafe import iterparse_safe, prepare_xml_bytes

    source = prepare_xml_bytes(read_net_bytes(net_path), str(net_path))
    found = set()
    for _event, element in iterparse_safe(source, events=("start",), tag="edge"):
        if element.get("function") == "crossing":
            found.add(element.get("id"))
    return frozenset(found)


class SumoTraffic:
    """One SUMO simulation on a build's network; ``step()`` advances it by the twin's step."""

    def __init__(self, net_path: str | Path, frame: NetFrame, config: TrafficConfig, demand: Demand,
                 odr=None) -> None:
        config.check()
        if config.vehicles and not demand.vehicle_routes:
            raise InputError("the demand has no vehicle routes", file=demand.source)
        if config.pedestrians and not demand.walks:
            raise InputError("the demand has no pedestrian walks", file=demand.source)
        if not _RUNNING.acquire(blocking=False):
            raise StageError("a SUMO simulation is already open in this process (libsumo runs one at a time)")
        self.net_path = Path(net_path)
        self.odr = odr
        self.junction_map = None
        self.frame = frame
        self.config = config
        self.demand = demand
        self.stats = TrafficStats()
        self.step_index = 0
        self._rng = np.random.default_rng(config.seed)
        self._next_vehicle = 0
        self._next_person = 0
        self._type_size: dict[str, tuple[float, float, float]] = {}
        self._vehicles: set[str] = set()  # added and not yet arrived or removed (pending ones included)
        self._persons: set[str] = set()
        self._ego_in_sumo = False
        self._ego_pose: tuple[float, float, float] | None = None
        self._closed = False
        self._started = False
        try:
            self.crossings = crossing_edges(self.net_path)
            self._start()
        except BaseException:
            self.close()
            raise

    @classmethod
    def from_build(cls, build_dir: str | Path, config: TrafficConfig,
                   work_dir: str | Path | None = None) -> SumoTraffic:
        from twin.traffic.buildfiles import build_files

        files = build_files(build_dir)
        frame = NetFrame.from_files(files.net, files.xodr)
        if config.demand is not None:
            demand = read_demand(config.demand)
        else:
            demand = generate_demand(files.net, config.seed, config.vehicles, config.pedestrians, work_dir)
        odr = None
        if config.junction_placement:
            from tavf_mapkit.opendrive.snapshot import load_build_map

            odr = load_build_map(files.xodr)
        return cls(files.net, frame, config, demand, odr)

    # --- life cycle ------------------------------------------------------------------------------------------

    def _start(self) -> None:
        c = self.config
        command = [sumo_binary(), "-n", str(self.net_path), "--step-length", repr(float(c.step_s)),
                   "--seed", str(int(c.seed)), "--begin", "0",
                   "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
                   # the twin detects and counts collisions with the ego itself, in pybullet
                   "--collision.action", "none", "--collision.check-junctions", "false",
                   "--time-to-teleport", repr(float(c.time_to_teleport_s)),
                   "--ignore-route-errors", "true", "--xml-validation", "never"]
        try:
            sumo_api.start(command)
            self._started = True
        except Exception as error:  # noqa: BLE001 -- libsumo raises its own exception types
            raise StageError(f"SUMO did not start: {error}", file=str(self.net_path)) from None
        for index, edges in enumerate(self.demand.vehicle_routes):
            try:
                sumo_api.route.add(f"r{index}", list(edges))
            except sumo_api.TraCIException as error:
                raise InputError(f"route {index} ({' '.join(edges[:5])}...) does not fit the network "
                                 f"{self.net_path.name}: {error}", file=self.demand.source) from None
        known = set(sumo_api.edge.getIDList())
        for walk in self.demand.walks:
            missing = [edge for edge in walk if edge not in known]
            if missing:
                raise InputError(f"walk edge {missing[0]!r} is not in the network {self.net_path.name}",
                                 file=self.demand.source)
        sumo_api.vehicletype.copy("DEFAULT_VEHTYPE", EGO_TYPE)
        sumo_api.vehicletype.setLength(EGO_TYPE, c.ego_length_m)
        sumo_api.vehicletype.setWidth(EGO_TYPE, c.ego_width_m)
        sumo_api.vehicletype.setHeight(EGO_TYPE, c.ego_height_m)
        if self.odr is not None and self.config.junction_placement:
            from twin.traffic.lanemap import JunctionLaneMap

            self.junction_map = JunctionLaneMap.build(self.odr, self.frame, sumo_api)
        self.links = self._read_signal_links()
        self._tls_ids = tuple(dict.fromkeys(self.links.tls_id))
        self._tls_rows = [np.flatnonzero(np.array(self.links.tls_id, dtype=object) == tls) for tls in self._tls_ids]
        self._tls_link = [self.links.link_index[rows] for rows in self._tls_rows]
        self._state_lengths: tuple[int, ...] = ()
        self._state_index = np.empty(0, dtype=int)
        self._populate(initial=True)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self._started:
                sumo_api.close()
        except Exception as error:  # noqa: BLE001 -- closing a crashed SUMO must not hide the original error
            log.debug("SUMO did not close cleanly: %s", error)
        finally:
            _RUNNING.release()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- per step --------------------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        return self.step_index * self.config.step_s

    def push_ego(self, x: float, y: float, yaw: float, z: float = 0.0) -> None:
        """Place the ego (its centre, local frame) in SUMO for the next step, so traffic reacts to it."""
        self._ego_pose = (float(x), float(y), float(yaw))

    def step(self) -> TrafficSnapshot:
        self._populate(initial=False)
        self._move_ego()
        sumo_api.simulationStep()
        self.step_index += 1
        self._after_step()
        return self.snapshot()

    def _move_ego(self) -> None:
        if self._ego_pose is None:
            return
        x, y, yaw = self._ego_pose
        half = 0.5 * self.config.ego_length_m
        front_x, front_y = x + half * math.cos(yaw), y + half * math.sin(yaw)
        net_x, net_y = (float(v) for v in self.frame.local_to_net(front_x, front_y))
        angle = float(self.frame.yaw_to_sumo_angle(yaw, front_x, front_y))
        try:
            if not self._ego_in_sumo:
                edge, _pos, _lane = sumo_api.simulation.convertRoad(net_x, net_y, False, "passenger")
                sumo_api.route.add(f"ego_route_{self.step_index}", [edge])
                sumo_api.vehicle.add(EGO_ID, f"ego_route_{self.step_index}", EGO_TYPE, departPos="0",
                                     departLane="best")
                sumo_api.vehicle.setLaneChangeMode(EGO_ID, 0)
                self._ego_in_sumo = True
            # keepRoute=2: map to the nearest lane whatever the route, as a car the twin drives anywhere
            sumo_api.vehicle.moveToXY(EGO_ID, "", -1, net_x, net_y, angle, keepRoute=2,
                                       matchThreshold=MATCH_THRESHOLD_M)
        except sumo_api.TraCIException as error:
            self.stats.ego_move_errors += 1
            self.stats.last_ego_error = str(error)

    def _populate(self, initial: bool) -> None:
        c = self.config
        if c.vehicles:
            for _ in range(c.vehicles - len(self._vehicles)):
                vehicle_id = f"{VEHICLE_PREFIX}{self._next_vehicle}"
                route = f"r{self._next_vehicle % len(self.demand.vehicle_routes)}"
                self._next_vehicle += 1
                # the first wave spreads over the network; later cars enter where their route begins
                sumo_api.vehicle.add(vehicle_id, route, departPos="random_free" if initial else "base",
                                     departSpeed="max" if initial else "desired", departLane="best")
                self._vehicles.add(vehicle_id)
                self.stats.inserted_vehicles += 1
        if c.pedestrians:
            for _ in range(c.pedestrians - len(self._persons)):
                person_id = f"{PERSON_PREFIX}{self._next_person}"
                walk = self.demand.walks[self._next_person % len(self.demand.walks)]
                self._next_person += 1
                first_length = sumo_api.lane.getLength(f"{walk[0]}_0")
                last_length = sumo_api.lane.getLength(f"{walk[-1]}_0")
                if len(walk) == 1:  # one edge: from somewhere in its first half to near its end
                    position = float(self._rng.uniform(0.0, 0.5)) * first_length
                    arrival = max(position + 0.5 * (first_length - position), min(position + 1.0, first_length))
                else:  # the first wave starts anywhere on its first edge, later people at its start
                    position = float(self._rng.uniform(0.0, 1.0)) * first_length if initial else 0.0
                    arrival = 0.5 * last_length
                sumo_api.person.add(person_id, walk[0], position)
                sumo_api.person.appendWalkingStage(person_id, list(walk), arrival)
                self._persons.add(person_id)
                self.stats.inserted_persons += 1

    def _after_step(self) -> None:
        for vehicle_id in sumo_api.simulation.getStartingTeleportIDList():
            if vehicle_id == EGO_ID:
                continue
            try:
                # its subscription goes first: SUMO fails the next step on a subscription to a removed car
                sumo_api.vehicle.unsubscribe(vehicle_id)
                sumo_api.vehicle.remove(vehicle_id, tc.REMOVE_TELEPORT)
                self.stats.teleports_removed += 1
            except sumo_api.TraCIException:
                pass
            self._vehicles.discard(vehicle_id)
        for vehicle_id in sumo_api.simulation.getArrivedIDList():
            if vehicle_id == EGO_ID:
                self._ego_in_sumo = False
            elif vehicle_id in self._vehicles:
                self._vehicles.discard(vehicle_id)
                self.stats.arrived_vehicles += 1
        for person_id in sumo_api.simulation.getArrivedPersonIDList():
            if person_id in self._persons:
                self._persons.discard(person_id)
                self.stats.arrived_persons += 1
        for vehicle_id in sumo_api.simulation.getDepartedIDList():
            if vehicle_id != EGO_ID:
                sumo_api.vehicle.subscribe(vehicle_id, _SUBSCRIBED)
        for person_id in sumo_api.simulation.getDepartedPersonIDList():
            sumo_api.person.subscribe(person_id, _SUBSCRIBED)

    # --- reading the state -----------------------------------------------------------------------------------

    def _size(self, type_id: str) -> tuple[float, float, float]:
        size = self._type_size.get(type_id)
        if size is None:
            domain = sumo_api.vehicletype
            size = (domain.getLength(type_id), domain.getWidth(type_id), domain.getHeight(type_id))
            self._type_size[type_id] = size
        return size

    def snapshot(self) -> TrafficSnapshot:
        vehicles = sumo_api.vehicle.getAllSubscriptionResults()
        persons = sumo_api.person.getAllSubscriptionResults()
        # the step's results still hold the cars removed after it (teleporting: off the network, invalid values)
        vehicles = {key: record for key, record in vehicles.items() if key in self._vehicles}
        records = list(vehicles.items()) + list(persons.items())
        n = len(records)
        is_person = np.zeros(n, dtype=bool)
        is_person[len(vehicles):] = True
        position = np.array([r[tc.VAR_POSITION3D] for _, r in records], dtype=float).reshape(n, 3)
        angle = np.array([r[tc.VAR_ANGLE] for _, r in records], dtype=float)
        speed = np.array([r[tc.VAR_SPEED] for _, r in records], dtype=float)
        type_id = tuple(r[tc.VAR_TYPE] for _, r in records)
        sizes = np.array([self._size(t) for t in type_id], dtype=float).reshape(n, 3)
        sumo_x, sumo_y = (np.asarray(v, dtype=float) for v in self.frame.net_to_local(position[:, 0], position[:, 1]))
        yaw = np.asarray(self.frame.sumo_angle_to_yaw(angle, position[:, 0], position[:, 1]), dtype=float)
        x, y, z = sumo_x.copy(), sumo_y.copy(), position[:, 2].copy()
        placed = np.zeros(n, dtype=bool)
        if self.junction_map is not None and n:
            lanes = [r[tc.VAR_LANE_ID] for _, r in records]
            inside = np.array([lane.startswith(":") for lane in lanes], dtype=bool) & ~is_person
            if inside.any():
                index = np.flatnonzero(inside)
                hit, px, py, pz, pyaw = self.junction_map.place(
                    [lanes[i] for i in index], [records[i][1][tc.VAR_LANEPOSITION] for i in index])
                index = index[hit]
                x[index], y[index], z[index], yaw[index] = px[hit], py[hit], pz[hit], pyaw[hit]
                placed[index] = True
        actors = Actors(tuple(k for k, _ in records), is_person, type_id, tuple(r[tc.VAR_ROAD_ID] for _, r in records),
                        x, y, z, yaw, speed, sizes[:, 0], sizes[:, 1], sizes[:, 2], placed, sumo_x, sumo_y)
        return TrafficSnapshot(self.step_index, self.time, actors, self._signal_state())

    def _signal_state(self) -> np.ndarray:
        if not self._tls_ids:
            return np.empty(0, dtype="<U1")
        letters = [sumo_api.trafficlight.getRedYellowGreenState(tls) for tls in self._tls_ids]
        lengths = tuple(len(text) for text in letters)
        if lengths != self._state_lengths:  # a program with another number of links: recompute the lookup
            starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(int)
            flat = np.full(len(self.links), -1, dtype=int)
            for start, length, rows, link in zip(starts, lengths, self._tls_rows, self._tls_link):
                flat[rows] = np.where(link < length, start + link, -1)
            self._state_lengths, self._state_index = lengths, flat
        joined = np.frombuffer(("".join(letters) + "o").encode("ascii"), dtype="S1")
        return joined[self._state_index].astype("<U1")  # index -1 picks the trailing "o" (off)

    def _read_signal_links(self) -> SignalLinks:
        rows: list[tuple[str, int, str, str]] = []
        for tls in sumo_api.trafficlight.getIDList():
            for index, links in enumerate(sumo_api.trafficlight.getControlledLinks(tls)):
                for in_lane, out_lane, _via in links:
                    rows.append((tls, index, in_lane, out_lane))
        stop = np.array([sumo_api.lane.getShape(r[2])[-2:] for r in rows], dtype=float).reshape(len(rows), 2, 2)
        out = np.array([sumo_api.lane.getShape(r[3])[0] for r in rows], dtype=float).reshape(len(rows), 2)
        sx, sy = self.frame.net_to_local(stop[:, 1, 0], stop[:, 1, 1])
        px, py = self.frame.net_to_local(stop[:, 0, 0], stop[:, 0, 1])
        ox, oy = self.frame.net_to_local(out[:, 0], out[:, 1])
        return SignalLinks(tuple(r[0] for r in rows), np.array([r[1] for r in rows], dtype=int),
                           tuple(r[2] for r in rows), tuple(r[3] for r in rows),
                           np.asarray(sx, dtype=float), np.asarray(sy, dtype=float),
                           np.arctan2(np.asarray(sy) - py, np.asarray(sx) - px),
                           np.asarray(ox, dtype=float), np.asarray(oy, dtype=float))
