"""``twin drive --traffic N --pedestrians M``: SUMO traffic around the ego, as a session hook.

Per step: the ego's pose goes into SUMO (``moveToXY``, keepRoute=2) and SUMO advances one step
(``before_step``); the ego's target speed is capped for red lights, leaders and people on its path
(``target_speed``); after the ego moved, the traffic boxes in pybullet are checked for contacts with it
(collisions, logged through ``session.record_collision``), and at the publish rate the traffic goes to the
UDM (``after_step``). metrics.json gets ``red_light_violations`` and a ``traffic`` section.

Options (the drive's option mapping): ``traffic``, ``pedestrians``, ``demand``, ``seed``; publishing needs
``udm`` (URL) and a token (``udm_token`` or the ``TWIN_UDM_TOKEN`` variable); ``traffic_publish_hz``
(default 10), ``traffic_validity_periods`` (3), ``traffic_publish_min_interval`` (wall seconds between
batches, default 0 = every batch; with a floor, a twin faster than real time merges batches, newest wins),
``perception_range`` (metres, 0 = off) and ``perception_noise`` (metres) make the ego a collective-perception
data provider. Features are built and posted in a child process (``publish_process.py``).
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from twin.session.hooks import Frame, SessionHook, SessionView
from twin.traffic.bodies import TrafficBodies
from twin.traffic.sumo import SumoTraffic, TrafficConfig

log = logging.getLogger(__name__)

RECORD_EVERY_S = 0.1  # traffic in the recording at 10 Hz


class TrafficHook(SessionHook):
    name = "traffic"

    def __init__(self, options: Mapping[str, Any] | None = None, **overrides: Any) -> None:
        options = {**(options or {}), **overrides}
        self.vehicles = int(options.get("traffic") or 0)
        self.pedestrians = int(options.get("pedestrians") or 0)
        demand = options.get("demand")
        self.demand = Path(demand) if demand else None
        self.udm_url = options.get("udm") or None
        self.udm_token = options.get("udm_token") or os.environ.get("TWIN_UDM_TOKEN") or None
        self.publish_hz = float(options.get("traffic_publish_hz") or 10.0)
        self.validity_periods = float(options.get("traffic_validity_periods") or 3.0)
        self.perception_range = float(options.get("perception_range") or 0.0)
        self.perception_noise = float(options.get("perception_noise") or 0.0)
        # wall seconds between batches handed to the UDM (default half a publish period; 0 = every batch)
        interval = options.get("traffic_publish_min_interval")
        self.publish_min_interval_s = None if interval is None else float(interval)
        self.traffic: SumoTraffic | None = None
        self.snapshot = None  # the latest TrafficSnapshot, for other hooks
        self.seconds = {"sumo": 0.0, "bodies": 0.0, "behaviour": 0.0, "contacts": 0.0, "udm": 0.0, "record": 0.0}
        self.collisions: list[tuple[float, str, float]] = []
        self._touching: set[str] = set()
        self.publishing = None
        self.publisher = None
        if options.get("map") is not None:
            from twin.traffic.buildfiles import build_files

            build_files(options["map"])  # no SUMO network (an OpenDRIVE build): one line before any setup

    # ------------------------------------------------------------------ life cycle
    def start(self, session: SessionView) -> None:
        from twin.traffic.behaviour import EgoBehaviour
        from twin.traffic.buildfiles import build_files
        from twin.traffic.demand import generate_demand, read_demand
        from twin.traffic.frames import NetFrame
        from twin.vehicle.params import MODEL_S

        self.params = MODEL_S
        seed = int(session.config.get("seed", 0))
        config = TrafficConfig(vehicles=self.vehicles, pedestrians=self.pedestrians, seed=seed,
                               step_s=float(session.dt), demand=self.demand, ego_length_m=MODEL_S.length,
                               ego_width_m=MODEL_S.width, ego_height_m=MODEL_S.height)
        config.check()
        files = build_files(session.build_dir)
        frame = NetFrame.from_files(files.net, files.xodr)
        if self.demand is not None:
            demand = read_demand(self.demand)
        else:
            demand = generate_demand(files.net, seed, self.vehicles, self.pedestrians, session.out_dir / "traffic")
        self.traffic = SumoTraffic(files.net, frame, config, demand, odr=session.odr)
        origin = getattr(session.world, "origin", (0.0, 0.0, 0.0))
        self.bodies = TrafficBodies(session.client_id, origin)
        self.behaviour = EgoBehaviour(self.traffic.links, MODEL_S.length, MODEL_S.width)
        self.dt = float(session.dt)
        self.publish_every = max(1, round(1.0 / (self.publish_hz * self.dt)))
        self.record_every = max(1, round(RECORD_EVERY_S / self.dt))
        self.ego_radius = 0.5 * math.hypot(MODEL_S.length, MODEL_S.width)
        if self.udm_url and self.udm_token:
            from twin.traffic.publish_process import TrafficPublisherProcess

            # features are built and posted in a child process: the loop only pickles the snapshot
            self.publisher = self.publishing = TrafficPublisherProcess(
                self.udm_url, self.udm_token, files.net, files.xodr, self.traffic.links,
                period_sim_s=self.publish_every * self.dt, validity_periods=self.validity_periods,
                min_interval_s=self.publish_min_interval_s)
            self.perception_rng = session.rng("traffic.perception")
        elif self.udm_url:
            log.warning("traffic is not published to the UDM: no token (--udm-token or TWIN_UDM_TOKEN)")

    def before_step(self, session: SessionView, t: float) -> None:
        started = time.perf_counter()
        ego = session.ego
        forward = self.params.cg_to_body_centre
        self.traffic.push_ego(ego.x + forward * math.cos(ego.yaw), ego.y + forward * math.sin(ego.yaw), ego.yaw)
        self.snapshot = self.traffic.step()
        middle = time.perf_counter()
        self.bodies.update(self.snapshot.actors)
        self.seconds["sumo"] += middle - started
        self.seconds["bodies"] += time.perf_counter() - middle

    def target_speed(self, session: SessionView, t: float, speed: float) -> float:
        if self.snapshot is None:
            return speed
        started = time.perf_counter()
        ego = session.ego
        forward = self.params.cg_to_body_centre
        centre = (ego.x + forward * math.cos(ego.yaw), ego.y + forward * math.sin(ego.yaw))
        cap = self.behaviour.cap(t, centre, ego.yaw, ego.speed,
                                 session.path_ahead(self.behaviour.config.look_ahead_m), self.snapshot)
        self.seconds["behaviour"] += time.perf_counter() - started
        return min(speed, cap.speed)

    def after_step(self, session: SessionView, frame: Frame) -> None:
        if self.snapshot is None:
            return
        started = time.perf_counter()
        contacts = self.bodies.contacts(session.ego_body_id, (frame.x, frame.y), self.ego_radius,
                                        self.snapshot.actors)
        touching = {contact.actor for contact in contacts}
        for contact in contacts:
            if contact.actor not in self._touching:  # one collision per contact episode
                kind = "person" if contact.is_person else "vehicle"
                self.collisions.append((frame.t, contact.actor, contact.depth_m))
                session.record_collision(frame.t, f"sumo-{kind}:{contact.actor}", f"depth {contact.depth_m:.3f} m")
        self._touching = touching
        self.seconds["contacts"] += time.perf_counter() - started
        if self.publishing is not None and frame.step % self.publish_every == 0:
            started = time.perf_counter()
            extra = None
            if self.perception_range > 0:
                from twin.traffic.publish import perceived_features

                extra = perceived_features(self.snapshot, self.traffic.frame, (frame.x, frame.y),
                                           self.perception_range, self.perception_noise, self.perception_rng,
                                           time.time() + self.validity_periods * self.publish_every * self.dt)
            self.publishing.publish(self.snapshot, extra)
            self.seconds["udm"] += time.perf_counter() - started
        if frame.step % self.record_every == 0:
            started = time.perf_counter()
            self._record(session, frame)
            self.seconds["record"] += time.perf_counter() - started

    def _record(self, session: SessionView, frame: Frame) -> None:
        try:
            from twin.recording import bus
        except ImportError:
            return
        recording = bus.recording_for(session)
        if recording is None:
            return
        from twin.traffic.record import TRAFFIC_CHANNEL, traffic_message

        recording.recorder.write(TRAFFIC_CHANNEL, frame.t, traffic_message(self.snapshot, self.behaviour.last))

    def finish(self, session: SessionView, metrics: dict[str, Any]) -> None:
        try:
            if self.publisher is not None:
                self.publisher.close()
            if self.traffic is not None:
                stats = self.traffic.stats
                metrics["red_light_violations"] = self.behaviour.red_light_violations
                section = {
                    "vehicles": self.vehicles, "pedestrians": self.pedestrians,
                    "collisions": len(self.collisions),
                    "inserted_vehicles": stats.inserted_vehicles, "inserted_persons": stats.inserted_persons,
                    "arrived_vehicles": stats.arrived_vehicles, "arrived_persons": stats.arrived_persons,
                    "teleports_removed": stats.teleports_removed, "ego_move_errors": stats.ego_move_errors,
                    "junction_chains_matched": getattr(self.traffic.junction_map, "matched_chains", 0),
                    "junction_chains_unmatched": getattr(self.traffic.junction_map, "unmatched_chains", 0),
                    "seconds": {key: round(value, 4) for key, value in self.seconds.items()},
                }
                if self.publisher is not None:
                    published = self.publisher.stats
                    section["udm"] = {"posts": published.posts, "objects": published.objects,
                                      "errors": dict(published.errors),
                                      "snapshots_sent": self.publisher.sent, "snapshots_held": self.publisher.held,
                                      "min_interval_s": self.publisher.min_interval_s}
                metrics["traffic"] = section
        finally:
            if self.traffic is not None:
                try:
                    self.bodies.clear()
                except Exception as error:  # noqa: BLE001 -- the world may already be gone after an error
                    log.debug("traffic bodies not removed: %s", error)
                self.traffic.close()
                self.traffic = None
