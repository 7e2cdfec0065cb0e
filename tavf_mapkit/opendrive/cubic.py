"""Piecewise cubic records keyed by s: elevation, superelevation, laneOffset, lane width and border.

One implementation serves every ``a + b*ds + c*ds^2 + d*ds^3`` record of OpenDRIVE. ``s0`` is absolute road s
(for lane widths the reader already adds the lane section start to @sOffset).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False, slots=True)
class CubicProfile:
    """Ascending record starts ``s0`` and coefficients; value 0 before the first record and when empty."""

    s0: np.ndarray
    coefficients: np.ndarray  # shape (n, 4): a, b, c, d
    extend_first: bool = False  # lane widths/borders: s a hair before the first record still uses it

    @staticmethod
    def from_records(records: list[tuple[float, float, float, float, float]],
                     extend_first: bool = False) -> "CubicProfile":
        if not records:
            return EMPTY_PROFILE
        array = np.asarray(records, dtype=float).reshape(-1, 5)
        if len(array) > 1:
            array = array[np.argsort(array[:, 0], kind="stable")]
        return CubicProfile._of_array(array, extend_first)

    @staticmethod
    def _of_array(array: np.ndarray, extend_first: bool) -> "CubicProfile":
        # two arrays of their own, not views of one: a view of a one-record profile keeps the (1, 5) array and
        # its object alive as well (a city has hundreds of thousands of lane widths, mostly of one record)
        s0, coefficients = array[:, 0].copy(), array[:, 1:].copy()
        s0.flags.writeable = False
        coefficients.flags.writeable = False
        return CubicProfile(s0, coefficients, extend_first)

    def __len__(self) -> int:
        return len(self.s0)

    def record_index(self, s: np.ndarray) -> np.ndarray:
        """Index of the record that governs each s (-1 before the first record unless extend_first)."""
        index = np.searchsorted(self.s0, s, side="right") - 1
        return np.maximum(index, 0) if self.extend_first else index

    def _evaluate(self, s, order: int) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        if not len(self.s0):
            return np.zeros_like(s)
        index = self.record_index(s)
        i = np.maximum(index, 0)
        ds = s - self.s0[i]
        a, b, c, d = self.coefficients[i].T
        if order == 0:
            value = a + ds * (b + ds * (c + ds * d))
        elif order == 1:
            value = b + ds * (2.0 * c + 3.0 * d * ds)
        else:
            value = 2.0 * c + 6.0 * d * ds
        return np.where(index >= 0, value, 0.0)

    def __call__(self, s) -> np.ndarray:
        return self._evaluate(s, 0)

    def derivative(self, s) -> np.ndarray:
        return self._evaluate(s, 1)

    def second_derivative(self, s) -> np.ndarray:
        return self._evaluate(s, 2)

    @property
    def is_zero(self) -> bool:
        return not len(self.s0) or not np.any(self.coefficients)


EMPTY_PROFILE = CubicProfile(np.zeros(0), np.zeros((0, 4)))
EMPTY_PROFILE.s0.flags.writeable = False
EMPTY_PROFILE.coefficients.flags.writeable = False


class ProfileInterner:
    """One CubicProfile for all records that are bit for bit the same: a city's lanes are mostly of a few widths
    (3.2 m from s=0) and netconvert gives every road the same flat elevation, so hundreds of thousands of
    profiles are a few thousand. Profiles are immutable (read-only arrays), so sharing them is safe."""

    def __init__(self):
        self.known: dict[tuple, CubicProfile] = {}

    def profile(self, records: list, extend_first: bool = False) -> CubicProfile:
        if not records:
            return EMPTY_PROFILE
        if len(records) == 1:  # nearly every profile: its key without making an array
            key = (_RECORD.pack(*records[0]), extend_first)
            found = self.known.get(key)
            if found is not None:
                return found
        array = np.asarray(records, dtype=float).reshape(-1, 5)
        if len(array) > 1:
            array = array[np.argsort(array[:, 0], kind="stable")]
        key = (array.tobytes(), extend_first)  # the bits (as _RECORD packs them): -0.0 and 0.0 are written apart
        found = self.known.get(key)
        if found is None:
            found = self.known[key] = CubicProfile._of_array(array, extend_first)
        return found


_RECORD = struct.Struct("=5d")  # a record's bits as a (1, 5) float64 array holds them


def evaluate_cubic(coefficients: np.ndarray, ds: np.ndarray) -> np.ndarray:
    """Horner evaluation of rows of (a, b, c, d) at ds (same length)."""
    a, b, c, d = coefficients.T
    return a + ds * (b + ds * (c + ds * d))


def cubic_minimum(coefficients: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact minimum of a + b x + c x^2 + d x^3 on [0, length] per row, and where it is (ends and stationary
    points are the only candidates)."""
    a, b, c, d = coefficients.T
    candidates = [np.zeros_like(length), np.maximum(length, 0.0)]
    # stationary points: b + 2c x + 3d x^2 = 0
    quadratic = np.abs(d) > 1e-15
    disc = 4.0 * c * c - 12.0 * d * b
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x1 = np.where(quadratic, (-2.0 * c + root) / (6.0 * d), np.where(np.abs(c) > 1e-15, -b / (2.0 * c), 0.0))
        x2 = np.where(quadratic, (-2.0 * c - root) / (6.0 * d), 0.0)
    for x in (x1, x2):
        inside = np.isfinite(x) & (x > 0) & (x < length) & ((disc >= 0) | ~quadratic)
        candidates.append(np.where(inside, x, 0.0))
    xs = np.column_stack(candidates)
    with np.errstate(over="ignore", invalid="ignore"):
        values = a[:, None] + xs * (b[:, None] + xs * (c[:, None] + xs * d[:, None]))
    best = np.argmin(values, axis=1)
    rows = np.arange(len(length))
    return values[rows, best], xs[rows, best]


def cubic_largest_magnitude(coefficients: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Exact max |a + b x + c x^2 + d x^3| on [0, length] per row."""
    lowest, _ = cubic_minimum(coefficients, length)
    highest, _ = cubic_minimum(-coefficients, length)
    return np.maximum(np.abs(lowest), np.abs(highest))
