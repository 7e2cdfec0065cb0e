"""Unit conversion for OpenDRIVE speed values."""

from __future__ import annotations

_SPEED_FACTORS = {"m/s": 1.0, "km/h": 1.0 / 3.6, "mph": 0.44704}


def speed_to_mps(value: str | None, unit: str | None) -> float | None:
    """A speed in m/s, or None for 'no limit' / 'undefined' / unparseable values."""
    if value is None:
        return None
    try:
        number = float(value)
    except ValueError:
        return None
    return number * _SPEED_FACTORS.get(unit or "m/s", 1.0)
