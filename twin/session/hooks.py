"""Extension points of a ``twin drive`` session: hooks see every step without owning the loop.

A hook is created once per session (by a factory from ``twin.session.plugins``), then called:

- ``start(session)`` after the world, the route and the ego exist, before the first step;
- ``before_step(session, t)`` before the ego is controlled and moved for sim time ``t`` (traffic moves here);
- ``target_speed(session, t, speed)`` may lower the ego's target speed in m/s (red light, leader, crossing);
- ``after_step(session, frame)`` with the immutable ``Frame`` of the step just done (publish, record here);
- ``finish(session, metrics)`` once at the end, also after an error; it may add keys to ``metrics``
  (e.g. ``red_light_violations``) before metrics.json is written, and must flush/close its files.

What a hook can use on ``session`` (see ``SessionView``): ``config`` (dict with ``seed``, ``map_sha256``
and every CLI option), ``out_dir`` (the temporary output folder, renamed into place at the end: write files
there), ``client_id`` (pybullet), ``world`` (``WorldBodies``), ``odr`` (``OpenDriveMap``), ``build_dir``,
``ego`` (current ``EgoPose``), ``ego_body_id``, ``dt``, ``rng(name)`` (an independent seeded numpy Generator per
name), ``path_ahead(distance_m)`` and ``record_collision(t, other, detail)``.

A hook that raises is logged (with its name and the step) and disabled for the rest of the session; the drive
goes on and the error is counted in metrics.json under ``hook_errors``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from twin.sensors.fix import GnssFix


@dataclass(frozen=True, slots=True)
class EgoPose:
    """The ego's state in the OpenDRIVE local frame (metres, radians, m/s); z is the ground under the body centre."""

    x: float
    y: float
    z: float
    yaw: float
    pitch: float = 0.0
    roll: float = 0.0
    speed: float = 0.0
    yaw_rate: float = 0.0


@dataclass(frozen=True, slots=True)
class Frame:
    """What happened in one fixed step; ``gnss`` is the fix produced this step, if the GNSS fired."""

    t: float
    step: int
    x: float
    y: float
    z: float
    yaw: float
    speed: float
    lat: float
    lon: float
    road_id: str
    lane_id: int
    gnss: GnssFix | None = None
    alt: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    steer: float = 0.0
    throttle: float = 0.0
    brake: float = 0.0


class SessionView(Protocol):
    """The part of ``twin.session.loop.Session`` hooks may rely on."""

    config: dict[str, Any]
    out_dir: Path
    client_id: int
    world: Any
    odr: Any
    build_dir: Path
    dt: float
    ego_body_id: int

    @property
    def ego(self) -> EgoPose: ...

    def rng(self, name: str) -> np.random.Generator: ...

    def path_ahead(self, distance_m: float) -> np.ndarray: ...

    def record_collision(self, t: float, other: str, detail: str = "") -> None: ...


class SessionHook:
    """Base class: every method is a no-op, override what you need."""

    name = "hook"

    def start(self, session: SessionView) -> None:
        pass

    def before_step(self, session: SessionView, t: float) -> None:
        pass

    def target_speed(self, session: SessionView, t: float, speed: float) -> float:
        return speed

    def after_step(self, session: SessionView, frame: Frame) -> None:
        pass

    def finish(self, session: SessionView, metrics: dict[str, Any]) -> None:
        pass
