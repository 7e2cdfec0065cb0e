"""Everything a drive depends on, in one immutable value (recorded with the session for replays)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class DriveConfig:
    map: Path
    out: Path
    route: Path | None = None
    route_mode: str = "replay"  # replay: the recording's path on the lane centres; legal: a drivable lane route
    random: bool = False
    duration: float | None = None  # s; None: 60 s for random routes, the whole trace for recorded ones
    seed: int = 0
    speed_kmh: float | None = None  # a fixed target speed instead of the limit / the recording
    dt: float = 0.05
    controller: str = "pure-pursuit"  # or "pid" (CARLA's lateral PID)
    vehicles: int = 1  # twin-controlled vehicles on random routes, the ego included
    gnss_rate: float = 10.0
    gnss_noise: float = 0.0  # m, standard deviation per axis
    gnss_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu: bool = True
    lidar: bool = False
    lidar_channels: int = 32
    lidar_columns: int = 1024
    lidar_rate: float = 10.0
    camera: bool = False
    camera_rate: float = 5.0
    gui: bool = False
    # load the whole collision world at start instead of streaming its tiles around the cars (the GUI always
    # does); the drive is the same either way (docs/twin.md, Collision world)
    whole_world: bool = False
    plot: bool = True
    pace: float | None = None  # at most this many times real time (1 = real time); None = as fast as it can
    plugins: dict[str, Any] = field(default_factory=dict)  # hook options: udm, record, traffic, ...

    @property
    def random_default_duration(self) -> float:
        return 60.0

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        plugins = data.pop("plugins")
        data.update(plugins)
        return {k: (str(v) if isinstance(v, Path) else list(v) if isinstance(v, tuple) else v)
                for k, v in data.items()}
