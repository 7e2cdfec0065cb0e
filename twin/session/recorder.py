"""Per-step records of the ego kept in preallocated arrays, and the session's output files."""

from __future__ import annotations

import numpy as np

from twin.session import outputs
from twin.session.hooks import Frame

_FIELDS = ("t", "x", "y", "z", "yaw", "speed", "lat", "lon", "lateral", "target_speed")


class Recorder:
    def __init__(self, capacity: int):
        self.n = 0
        self.columns = {name: np.empty(capacity) for name in _FIELDS}
        self.road: list[str] = []
        self.lane = np.empty(capacity, dtype=np.int64)
        self.surface = np.empty(capacity, dtype=np.int64)  # pybullet body under the ego's centre, -1 for none
        self.fixes = []
        self.imu = []
        self.lidar_scans = 0
        self.camera_frames = 0

    def add(self, frame: Frame, fleet) -> None:
        i = self.n
        c = self.columns
        c["t"][i], c["x"][i], c["y"][i], c["z"][i] = frame.t, frame.x, frame.y, frame.z
        c["yaw"][i], c["speed"][i], c["lat"][i], c["lon"][i] = frame.yaw, frame.speed, frame.lat, frame.lon
        control = fleet.control
        c["lateral"][i] = control.projection.lateral[0] if control is not None else 0.0
        c["target_speed"][i] = control.target_speed[0] if control is not None else 0.0
        self.road.append(frame.road_id)
        self.lane[i] = frame.lane_id
        self.surface[i] = fleet.ground.centre_body[0]
        if frame.gnss is not None:
            self.fixes.append(frame.gnss)
        self.n = i + 1

    def column(self, name: str) -> np.ndarray:
        return self.columns[name][: self.n]

    def write(self, session, metrics: dict) -> None:
        out = session.out_dir
        col = self.column
        outputs.write_trajectory(out / "trajectory.csv", col("t"), col("x"), col("y"), col("z"), col("yaw"),
                                 col("speed"), col("lat"), col("lon"), self.road, self.lane[: self.n])
        outputs.write_gnss(out / "gnss.csv", self.fixes)
        if self.imu:
            outputs.write_imu(out / "imu.csv", self.imu)
        outputs.write_collisions(out / "collisions.csv", session.fleet.counters.collisions)
        outputs.write_metrics(out / "metrics.json", metrics)
        if session.last_camera is not None:
            import matplotlib.image

            matplotlib.image.imsave(out / "camera.png", session.last_camera.rgb)
        if session.drive_config.plot:
            from twin.session.plot import plot_drive

            plot_drive(out / "drive.png", session, self)
