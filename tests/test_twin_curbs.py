"""What the twin counts as hitting a curb: a wheel rising more than ``CURB_STEP`` within ``CURB_RUN`` of its
travel (an edge), not a wheel rising that much in one step over steep ground."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.test_twin_vehicle import DT, _ramp, _straight_fleet, client  # noqa: F401 -- client is a fixture
from twin.vehicle.body import CURB_STEP


def test_a_steep_street_at_speed_is_no_curb(client):  # noqa: F811
    """A wheel rises 12 cm per step on a 15 degree ramp at 8 m/s, more than a curb's 8 cm, but over 40 cm of
    travel: ground, not an edge (Town07's junction 763, whose connecting roads disagree by 0.6 m, rises as
    steeply where their footprints overlap). The 15 cm step of test_twin_vehicle is still a curb."""
    cid, _ = client
    start, angle = 20.0, math.radians(15.0)
    _ramp(cid, 15.0, start)
    fleet = _straight_fleet(cid)
    rises = []
    for step in range(1, 200):
        before = fleet.ground.wheel_z[0].copy()
        fleet.step(step * DT)
        rises.append(float(np.max(fleet.ground.wheel_z[0] - before)))
        if fleet.state.x[0] > start + 12.0:
            break
    assert max(rises) > CURB_STEP and fleet.state.speed[0] > 6.0
    assert fleet.counters.collisions == [] and fleet.counters.resets[0] == 0
    assert fleet.ground.pitch[0] == pytest.approx(angle, abs=1e-3)
