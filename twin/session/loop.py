"""One ``twin drive`` session: set up the world, the route and the car, step at a fixed dt, write outputs.

Order of a step (t = step * dt): hooks ``before_step`` -> target speed caps from hooks -> the fleet is
controlled, moved and grounded -> sensors that are due -> the ego's ``Frame`` -> hooks ``after_step``.
Everything random draws from ``rng(name)``: one numpy Generator per component, seeded from the session
seed and the name, so adding a sensor never changes the route another component drew.
"""

from __future__ import annotations

import gc
import logging
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from tavf_mapkit.errors import InputError, MapkitError
from twin.session.config import DriveConfig
from twin.session.hooks import EgoPose, Frame, SessionHook

log = logging.getLogger(__name__)


def freeze_long_lived(collect: bool = True) -> None:
    """Exempt every object alive now from the cyclic garbage collector's scans (``gc.freeze``), after a
    collection unless ``collect`` is False (a map just loaded: millions of objects and hardly a cycle to free, the
    walk over them would cost a region's start a second)."""
    if collect:
        gc.collect()
    gc.freeze()


class Session:
    """Build with ``Session(config, hooks)``, then ``run()`` -> metrics dict (outputs are in ``config.out``)."""

    def __init__(self, config: DriveConfig, hooks: list[SessionHook] | None = None):
        from tavf_mapkit.lanegraph import LaneGraph
        from tavf_mapkit.opendrive.snapshot import load_build_map
        from twin.session.outputs import output_folder
        from twin.sim.build import Build, georeference_for_driving

        started = time.perf_counter()
        if config.dt <= 0 or config.dt > 0.5:
            raise InputError(f"--dt must be in (0, 0.5] s, not {config.dt:g}")
        if config.vehicles < 1:
            raise InputError("--vehicles must be at least 1 (the ego)")
        if not config.random and config.route is None:
            raise InputError("choose a route: --random or --route TRACE")
        self.hooks = list(hooks or [])
        self.build = Build.open(config.map)
        self.build_dir = self.build.path
        self.odr = load_build_map(self.build.xodr)  # from the build's snapshot: a region's map in seconds
        # a region's map is millions of long-lived objects: the cyclic collector would walk them again and
        # again as the lane graph and routes allocate (seconds of a region's start); refcounting still frees
        freeze_long_lived(collect=False)
        self.georeference, fallback = georeference_for_driving(self.odr)
        if fallback:
            log.warning("%s has no geoReference: lat/lon are placed as CARLA places such maps, local (0, 0) at "
                        "0 deg N 0 deg E", self.build.xodr.name)
        self.graph = None
        if config.random or config.vehicles > 1:  # random routes: the lane graph a kept plan holds, if any
            from twin.planning.route_cache import kept_lane_graph

            self.graph = kept_lane_graph(self.odr, self.build.xodr, self.build.map_sha256)
        if self.graph is None:
            self.graph = LaneGraph.from_opendrive(self.odr)
        if len(self.graph) == 0:
            raise InputError("the map has no driving lanes", file=str(self.build.xodr))
        self.dt = float(config.dt)
        self._rngs: dict[str, np.random.Generator] = {}
        self.config: dict[str, Any] = {**config.as_dict(), "map_sha256": self.build.map_sha256,
                                       "map_name": self.build.name}
        self.drive_config = config
        self.route = None  # a RecordedRoute for --route
        self._prepare_routes(config)  # before the world: a bad trace fails fast
        self.output = output_folder(config.out)
        self.out_dir: Path = self.output.staging
        self.world = None
        try:
            self._setup(config)
        except BaseException:
            self.close()
            self.output.discard()
            raise
        freeze_long_lived()  # the lane graph, lines and routes, for the loop's sake
        self.setup_seconds = time.perf_counter() - started

    # ------------------------------------------------------------------ API for hooks
    def rng(self, name: str) -> np.random.Generator:
        """An independent generator per component name, the same sequence for the same seed."""
        if name not in self._rngs:
            self._rngs[name] = np.random.default_rng([int(self.drive_config.seed), zlib.crc32(name.encode())])
        return self._rngs[name]

    @property
    def client_id(self) -> int:
        return self.world.client_id

    @property
    def ego(self) -> EgoPose:
        s, g = self.fleet.state, self.fleet.ground
        return EgoPose(float(s.x[0]), float(s.y[0]), float(g.z[0]), float(s.yaw[0]), float(g.pitch[0]),
                       float(g.roll[0]), float(s.speed[0]), float(s.yaw_rate[0]))

    @property
    def ego_body_id(self) -> int:
        return self.fleet.bodies.body_ids[0]

    def path_ahead(self, distance_m: float) -> np.ndarray:
        """(n, 3) points of the ego's planned path from its position on, up to ``distance_m`` metres."""
        return self.fleet.buffer.path_ahead(0, distance_m)

    def record_collision(self, t: float, other: str, detail: str = "") -> None:
        self.fleet.record_collision(t, 0, "hook", other, detail)

    # ------------------------------------------------------------------ setup
    def _prepare_routes(self, config: DriveConfig) -> None:
        from twin.map.lanelines import LaneLines
        from twin.planning.chunks import LaneCodes

        self.lines = LaneLines(self.graph)
        self.codes = LaneCodes(self.graph)
        self.random_routes = None
        if config.random or config.vehicles > 1:
            from twin.planning.random_routes import RandomRoutes

            # read back from the plan of an earlier drive on this map and code, else computed and kept
            self.random_routes = RandomRoutes.cached(self.graph, self.lines, self.build.xodr, self.build.map_sha256)
        if config.route is not None:
            from twin.planning.recorded import RecordedRoute

            self.route = RecordedRoute.from_file(config.route, self.odr, self.graph, self.lines, self.codes,
                                                 config.route_mode)

    def _ego_chunks(self, config: DriveConfig):
        from twin.planning.chunks import with_speed

        if self.route is not None:
            chunks = self.route.chunks()
        else:
            chunks = self.random_routes.chunks(self.codes, self.rng("route.0"))
        return with_speed(chunks, None if config.speed_kmh is None else config.speed_kmh / 3.6)

    def _setup(self, config: DriveConfig) -> None:
        from twin.control.pid import PidLateral
        from twin.control.purepursuit import PurePursuit
        from twin.planning.buffer import PathBuffer
        from twin.planning.chunks import with_speed
        from twin.planning.local_planner import LocalPlanner
        from twin.session.fleet import Fleet
        from twin.sim.world import SimWorld, sensor_reach
        from twin.vehicle.body import VehicleBodies
        from twin.vehicle.dynamics import BicycleModel
        from twin.vehicle.params import MODEL_S

        # the collision world streamed around the cars (a region's start and memory do not grow with the map);
        # whole for the GUI, where a person looks at the map
        self.world = SimWorld(self.build, self.dt, gui=config.gui, stream=not (config.gui or config.whole_world),
                              reach_m=sensor_reach(config.lidar, config.camera))
        n = config.vehicles
        controllers = {"pid": lambda: PidLateral(n, self.dt), "pure-pursuit": lambda: PurePursuit(n)}
        if config.controller not in controllers:
            raise InputError(f"unknown controller {config.controller!r} (choose pid or pure-pursuit)")
        buffer = PathBuffer(n)
        planner = LocalPlanner(buffer, controllers[config.controller](), MODEL_S, n, self.dt)
        bodies = VehicleBodies(self.world.client_id, MODEL_S, n, origin=self.world.origin, world=self.world)
        self.fleet = Fleet(BicycleModel(MODEL_S), bodies, buffer, planner, self.dt, self.world.solid_ids,
                           self.world.body_names)
        speed = None if config.speed_kmh is None else config.speed_kmh / 3.6
        buffer.assign(0, self._ego_chunks(config))
        for i in range(1, n):
            buffer.assign(i, with_speed(self.random_routes.chunks(self.codes, self.rng(f"route.{i}")), speed))
        self.fleet.place_on_paths()
        self._setup_sensors(config)

    def _setup_sensors(self, config: DriveConfig) -> None:
        from twin.sensors.gnss import GnssConfig, GnssSensor
        from twin.sensors.odometry import ImuConfig, ImuSensor

        sigma = float(config.gnss_noise)
        if sigma < 0:
            raise InputError("--gnss-noise must not be negative")
        self.gnss = GnssSensor(self.georeference, GnssConfig(config.gnss_rate, (sigma, sigma, sigma),
                                                                 tuple(config.gnss_bias)), self.rng("gnss"), self.dt)
        self.imu = ImuSensor(ImuConfig(), self.rng("imu"), self.dt) if config.imu else None
        self.lidar = self.camera = None
        self.last_lidar = self.last_camera = None
        if config.lidar:
            from twin.sensors import embree
            from twin.sensors.lidar import LidarConfig, LidarSensor

            scene = None
            if embree.available():
                scene = embree.EmbreeWorld.following(self.world.stream) if self.world.stream is not None else \
                    embree.EmbreeWorld(self.build.collision_world.parent, self.world.bodies)
            self.lidar = LidarSensor(self.client_id, LidarConfig(config.lidar_channels, config.lidar_columns,
                                                                 config.lidar_rate), self.dt,
                                     origin=self.world.origin, embree=scene, world=self.world)
            self.lidar.ignore_ids = frozenset(self.fleet.bodies.body_ids)
        if config.camera:
            from twin.sensors.camera import CameraConfig, CameraSensor

            self.camera = CameraSensor(self.client_id, CameraConfig(rate_hz=config.camera_rate), self.dt,
                                       origin=self.world.origin)

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
        gc.unfreeze()  # what this session froze may be collected again (many sessions run in one process)

    # ------------------------------------------------------------------ hooks
    def _call_hooks(self, method: str, *args) -> list:
        results = []
        for hook in list(self.hooks):
            try:
                results.append(getattr(hook, method)(self, *args))
            except MapkitError as error:
                if method == "start":  # the user asked for this plug-in and gave it bad input: say so, stop
                    raise
                self._disable_hook(hook, method, error)
            except Exception as error:  # noqa: BLE001 -- a plug-in must not take the drive down, nor fail silently
                self._disable_hook(hook, method, error)
        return results

    def _disable_hook(self, hook, method: str, error: BaseException) -> None:
        name = getattr(hook, "name", type(hook).__name__)
        log.error("hook %s failed in %s at step %d and is disabled: %s: %s", name, method, self.step_index,
                  type(error).__name__, error)
        self.hook_errors.append(f"{name}.{method} at step {self.step_index}: {type(error).__name__}: {error}")
        self.hooks.remove(hook)

    def _speed_cap(self, t: float) -> np.ndarray | None:
        """The ego's target-speed cap from the hooks, None without hooks or when no hook lowers it.

        Each hook sees the route's speed at the ego (or the lowest value an earlier hook returned); a value
        that is not lower than the route's speed changes nothing, so idle hooks never alter the drive.
        """
        if not self.hooks or self.fleet.control is None:
            return None
        fleet = self.fleet
        route_speed = float(fleet.buffer.allowed_speed(fleet.control.projection.s, fleet.planner.decel)[0])
        speed = route_speed
        for hook in list(self.hooks):
            try:
                value = hook.target_speed(self, t, speed)
            except Exception as error:  # noqa: BLE001 -- same policy as _call_hooks
                name = getattr(hook, "name", type(hook).__name__)
                log.error("hook %s failed in target_speed at step %d and is disabled: %s: %s", name,
                          self.step_index, type(error).__name__, error)
                self.hook_errors.append(f"{name}.target_speed at step {self.step_index}: {error}")
                self.hooks.remove(hook)
                continue
            if value is not None and np.isfinite(value):
                speed = min(speed, max(float(value), 0.0))
        if speed >= route_speed:
            return None
        cap = np.full(fleet.count, np.inf)
        cap[0] = speed
        return cap

    # ------------------------------------------------------------------ the loop
    def run(self) -> dict:
        from twin.session.recorder import Recorder

        config = self.drive_config
        duration = config.duration
        if duration is None:
            duration = config.random_default_duration if self.route is None else 24 * 3600.0
        steps = round(duration / self.dt)
        self.step_index = 0
        self.hook_errors: list[str] = []
        recorder = Recorder(steps + 1)
        self.recorder = recorder
        failed = True
        wall_start = time.perf_counter()
        try:
            self._call_hooks("start")
            loop_start = time.perf_counter()
            for step in range(steps + 1):
                self.step_index = step
                t = step * self.dt
                if step > 0:
                    if self.hooks:
                        self._call_hooks("before_step", t)
                    self.fleet.step(t, self._speed_cap(t))
                frame = self._frame(step, t)
                recorder.add(frame, self.fleet)
                if self.imu is not None:
                    recorder.imu.append(self.imu_sample)
                if self.hooks:
                    self._call_hooks("after_step", frame)
                if self.route is not None and step > 0 and self._route_done():
                    break
                if config.pace:
                    # sleeping only changes when a step happens, never what it computes: runs stay identical
                    ahead = loop_start + t / config.pace - time.perf_counter()
                    if ahead > 0:
                        time.sleep(ahead)
            wall = time.perf_counter() - loop_start
            metrics = self._metrics(recorder, wall, self.setup_seconds + (loop_start - wall_start))
            failed = False
        finally:
            if failed:
                self._call_hooks("finish", {"failed": True})
                self.close()
                self.output.discard()
        self._call_hooks("finish", metrics)
        metrics["hook_errors"] = len(self.hook_errors)
        if self.hook_errors:
            metrics["hook_error_messages"] = self.hook_errors
        try:
            recorder.write(self, metrics)
            self.close()
            self.output.commit()
        except BaseException:
            self.close()
            self.output.discard()
            raise
        return metrics

    def _route_done(self) -> bool:
        fleet = self.fleet
        return bool(fleet.buffer.at_end(fleet.control.projection.s[:1], margin=2.0)[0] and fleet.state.speed[0] < 0.5)

    def _frame(self, step: int, t: float) -> Frame:
        fleet = self.fleet
        s, g = fleet.state, fleet.ground
        x, y, z, yaw = float(s.x[0]), float(s.y[0]), float(g.z[0]), float(s.yaw[0])
        lon, lat = self.georeference.local_to_wgs84(x, y)
        fix = self.gnss.measure(t, x, y, z) if self.gnss.due(step) else None
        if self.imu is not None:
            self.imu_sample = self.imu.measure(t, float(s.vx[0]), float(s.vy[0]), float(s.yaw_rate[0]),
                                               float(g.pitch[0]))
        if self.lidar is not None and self.lidar.due(step):
            self.last_lidar = self.lidar.scan(t, x, y, z, yaw, float(g.pitch[0]), float(g.roll[0]))
            self.recorder.lidar_scans += 1
        if self.camera is not None and self.camera.due(step):
            self.last_camera = self.camera.capture(t, x, y, z, yaw, float(g.pitch[0]))
            self.recorder.camera_frames += 1
        code = int(fleet.buffer.lane[0, fleet.buffer.base[0]])
        control = fleet.control
        return Frame(t=t, step=step, x=x, y=y, z=z, yaw=yaw, speed=float(s.speed[0]), lat=float(lat),
                     lon=float(lon), road_id=self.codes.road_id(code), lane_id=self.codes.lane_id(code), gnss=fix,
                     alt=z + self.gnss._z0, pitch=float(g.pitch[0]), roll=float(g.roll[0]),
                     steer=float(control.steer[0]) if control is not None else 0.0,
                     throttle=float(control.throttle[0]) if control is not None else 0.0,
                     brake=float(control.brake[0]) if control is not None else 0.0)

    def _metrics(self, recorder, wall: float, setup: float) -> dict:
        from twin.session.metrics import session_metrics

        return session_metrics(self, recorder, wall, setup)
