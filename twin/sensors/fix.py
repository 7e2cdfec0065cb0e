"""A GNSS fix as the receiver reports it: WGS84 plus the (noisy) local position it came from."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class GnssFix:
    """One fix. ``x``/``y``/``z`` are the noisy position in the OpenDRIVE local frame that produced lat/lon/alt."""

    t: float
    lat: float
    lon: float
    alt: float
    x: float
    y: float
    z: float
    sigma_m: float
