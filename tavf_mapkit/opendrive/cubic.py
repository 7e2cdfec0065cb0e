"""Piecewise cubic records keyed by s: elevation, superelevation, laneOffset, lane width and border.

One implementation serves every ``a + b*ds + c*ds^2 + d*ds^3`` record of OpenDRIVE. ``s0`` is absolute road s
(for lane widths the reader already adds the lane section start to @sOffset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
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
        order = np.argsort(array[:, 0], kind="stable")
        array = array[order]
        return CubicProfile(np.ascontiguousarray(array[:, 0]), np.ascontiguousarray(array[:, 1:]), extend_first)

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


def evaluate_cubic(coefficients: np.ndarray, ds: np.ndarray) -> np.ndarray:
    """Horner evaluation of rows of (a, b, c, d) at ds (same length)."""
    a, b, c, d = coefficients.T
    return a + ds * (b + ds * (c + ds * d))
