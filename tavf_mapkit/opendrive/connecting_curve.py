"""A junction's connecting road: a reference line from one pose to another, and cubic profiles along it.

The line is a cubic Hermite curve written as one paramPoly3 (pRange normalized): it starts at (x0, y0) with
heading h0 and ends at (x1, y1) with heading h1 exactly, so lanes built on it join their neighbours G1. Both
tangents are as long as those of a circular arc through the same turn (2 tan(theta/4) / sin(theta/2) times the
chord: 1 for a straight line, 2 for a U-turn), which makes a symmetric turn nearly that arc. @length is the
curve's true arc length, integrated with the reader's own quadrature, so s along it is arc length.

Where the two poses admit no road -- the target lies behind the start and the start behind the target (both
ends head away from the other: more than a right angle plus OBLIQUE off the chord; a U-turn may end behind its
start, but it heads towards it at one end), the curve reverses (a cusp) or winds far beyond the turn (a loop)
-- ``problem`` says so and the caller drops the link instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import Geometry, GeometryKind, param_poly3_length

#: below this chord (m) the two poses are one point: the curve is a pivot in place, not checked for sense
TOUCHING = 1e-3
#: shortest tangent (m): two poses at one point still get a curve of positive length
MIN_TANGENT = 1e-3
#: how much more than a right angle both ends' headings may be off the chord (a U-turn between lanes that end
#: side by side is exactly a right angle off at both ends; at a skewed road end one end somewhat more)
OBLIQUE = math.radians(20.0)
#: the curve may turn this much further than the net turn (S-bends of lane shifts need some) before it loops
SPARE_TURN = math.pi
#: slowest point of the parametrisation relative to the fastest: below it the curve (nearly) reverses
CUSP_SPEED = 0.02


@dataclass(frozen=True)
class ConnectingCurve:
    geometry: Geometry  # the paramPoly3, at s = 0
    length: float  # true arc length = geometry.length
    problem: str | None = None  # why no road should take this shape, or None


def wrap(angle):
    """Angle wrapped to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def hermite_curve(x0: float, y0: float, h0: float, x1: float, y1: float, h1: float) -> ConnectingCurve:
    """The G1 cubic from pose (x0, y0, h0) to pose (x1, y1, h1)."""
    cos0, sin0 = math.cos(h0), math.sin(h0)
    dx, dy = x1 - x0, y1 - y0
    qx, qy = cos0 * dx + sin0 * dy, -sin0 * dx + cos0 * dy  # the end in the start's frame
    turn = float(wrap(h1 - h0))
    theta = abs(turn)
    chord = math.hypot(qx, qy)
    ratio = 1.0 if theta < 1e-9 else 2.0 * math.tan(theta / 4.0) / math.sin(theta / 2.0)
    m = max(ratio * chord, MIN_TANGENT)
    cos_t, sin_t = math.cos(turn), math.sin(turn)
    # Hermite basis unfolded into power form: P(0) = 0, P'(0) = (m, 0), P(1) = q, P'(1) = m (cos, sin)
    params = (0.0, m, 3 * qx - 2 * m - m * cos_t, -2 * qx + m + m * cos_t,
              0.0, 0.0, 3 * qy - m * sin_t, -2 * qy + m * sin_t, 1.0)
    length = float(param_poly3_length(np.array([params]), np.array([1.0]))[0])
    geometry = Geometry(0.0, float(x0), float(y0), float(h0), length, GeometryKind.PARAM_POLY3, params)
    problem = None
    if chord >= TOUCHING:
        bearing = math.atan2(qy, qx)  # of the chord, in the start's frame
        off = min(abs(float(wrap(bearing))), abs(float(wrap(turn - bearing))))
        if off > math.pi / 2 + OBLIQUE:  # both ends: a U-turn may end behind its start, but it turns to it
            problem = (f"the lanes it joins lie behind one another (both ends head {math.degrees(off):.0f} "
                       f"degrees or more away from the other end)")
        else:
            problem = _problem(params, theta)
    return ConnectingCurve(geometry, length, problem)


#: points at which a curve's speed is checked for a cusp
_CUSP_SAMPLES = 257


def reverses(params: np.ndarray, p_end: np.ndarray | float = 1.0) -> np.ndarray:
    """Per paramPoly3 (rows of its nine parameters, over p in [0, p_end]) whether it (nearly) reverses on itself:
    its slowest point slower than CUSP_SPEED times its fastest. No chain of arcs, and no lane, follows a cusp."""
    params = np.atleast_2d(np.asarray(params, dtype=float))
    p = np.broadcast_to(np.asarray(p_end, dtype=float), (len(params),))[:, None] * np.linspace(
        0.0, 1.0, _CUSP_SAMPLES)[None, :]
    du = params[:, 1:2] + p * (2 * params[:, 2:3] + 3 * params[:, 3:4] * p)
    dv = params[:, 5:6] + p * (2 * params[:, 6:7] + 3 * params[:, 7:8] * p)
    speed = np.hypot(du, dv)
    return speed.min(axis=1) < CUSP_SPEED * speed.max(axis=1)


def _problem(params, theta: float) -> str | None:
    """Why the curve is no road (a cusp or a loop), or None."""
    if reverses(params)[0]:
        return "the curve would reverse on itself (a cusp)"
    p = np.linspace(0.0, 1.0, _CUSP_SAMPLES)
    du = params[1] + p * (2 * params[2] + 3 * params[3] * p)
    dv = params[5] + p * (2 * params[6] + 3 * params[7] * p)
    winding = float(np.abs(np.diff(np.unwrap(np.arctan2(dv, du)))).sum())
    if winding > theta + SPARE_TURN:
        return (f"the curve would wind {math.degrees(winding):.0f} degrees for a turn of "
                f"{math.degrees(theta):.0f} (a loop)")
    return None


def smooth_step(start: float, end: float, length: float) -> np.ndarray:
    """Coefficients (a, b, c, d) of the cubic from ``start`` to ``end`` over ``length`` with zero slope at both
    ends (a lane width or offset that joins constant neighbours without a kink)."""
    delta = end - start
    return np.array([start, 0.0, 3.0 * delta / length ** 2, -2.0 * delta / length ** 3])


def hermite_profile(start: float, start_slope: float, end: float, end_slope: float, length: float) -> CubicProfile:
    """One cubic record over [0, length] with the given values and slopes at both ends (e.g. an elevation that
    continues both neighbours' grades)."""
    delta = end - start
    c = (3.0 * delta - (2.0 * start_slope + end_slope) * length) / length ** 2
    d = (-2.0 * delta + (start_slope + end_slope) * length) / length ** 3
    return CubicProfile(np.zeros(1), np.array([[start, start_slope, c, d]]))


def cubic_record(coefficients: np.ndarray, extend_first: bool = True) -> CubicProfile:
    """A profile of one record at s = 0."""
    return CubicProfile(np.zeros(1), np.asarray(coefficients, dtype=float).reshape(1, 4), extend_first)
