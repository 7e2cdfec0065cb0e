"""Which side of the road traffic keeps to: from where the map is, from OpenDRIVE's ``rule``, or the user's word.

Where a map is: the country under its centre, found offline. timezonefinder ships the polygons of the IANA
time zones (timezone-boundary-builder, built from OpenStreetMap boundaries, territorial waters included), and
every zone of a country lies inside that country; tzdata's ``zone.tab`` names the country of each zone. A
point-based geocoder (nearest town) would be slower to load (seconds, 190 MB) and wrong near borders that
split driving sides (Hong Kong / Shenzhen, Macau / Zhuhai).

The countries and territories that drive on the left are :data:`LEFT_HAND_COUNTRIES` (ISO 3166-1 alpha-2),
from the list in Wikipedia's "Left- and right-hand traffic" (countries and territories driving on the left,
as of 2024). Everywhere else, and on the open sea, traffic keeps to the right.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from tavf_mapkit.errors import InputError

SIDES = ("left", "right")
CHOICES = ("auto", "left", "right")

LEFT_HAND_COUNTRIES = frozenset({
    # Africa
    "BW", "KE", "LS", "MU", "MW", "MZ", "NA", "SC", "SH", "SZ", "TZ", "UG", "ZA", "ZM", "ZW",
    # Asia
    "BD", "BN", "BT", "HK", "ID", "IN", "JP", "LK", "MO", "MV", "MY", "NP", "PK", "SG", "TH", "TL",
    # Europe (Gibraltar drives on the right)
    "CY", "GB", "GG", "IE", "IM", "JE", "MT",
    # Americas and the Caribbean
    "AG", "AI", "BB", "BM", "BS", "DM", "FK", "GD", "GY", "JM", "KN", "KY", "LC", "MS", "SR", "TC", "TT",
    "VC", "VG", "VI",
    # Oceania
    "AU", "CC", "CK", "CX", "FJ", "KI", "NF", "NR", "NU", "NZ", "PG", "PN", "SB", "TK", "TO", "TV", "WS",
})


@dataclass(frozen=True)
class DrivingSide:
    """The side traffic keeps to and why (``reason`` is one line for the manifest and the build output)."""

    side: str  # "left" or "right"
    source: str  # "option", "location", "opendrive", "sumo-net" or "default"
    why: str
    country: str | None = None
    timezone: str | None = None

    @property
    def lefthand(self) -> bool:
        return self.side == "left"

    @property
    def reason(self) -> str:
        return f"{self.side}-hand traffic: {self.why}"

    def to_dict(self) -> dict:
        record = {"side": self.side, "source": self.source, "why": self.why, "reason": self.reason}
        if self.country is not None:
            record["country"] = self.country
        if self.timezone is not None:
            record["timezone"] = self.timezone
        return record

    @staticmethod
    def from_dict(record: dict) -> DrivingSide:
        return DrivingSide(record["side"], record["source"], record["why"], record.get("country"),
                           record.get("timezone"))


def check_choice(value, where: str | None = None) -> str:
    """``value`` as one of auto/left/right, or a one-line InputError."""
    if not isinstance(value, str) or value.lower() not in CHOICES:
        raise InputError(f"driving_side must be one of {', '.join(CHOICES)}, not {value!r}", file=where)
    return value.lower()


@functools.lru_cache(maxsize=1)
def _timezone_finder():
    from timezonefinder import TimezoneFinder

    return TimezoneFinder()


@functools.lru_cache(maxsize=1)
def _zone_countries() -> dict[str, str]:
    """IANA zone name -> ISO country code, from tzdata's zone.tab (one country per zone)."""
    from importlib import resources

    text = resources.files("tzdata").joinpath("zoneinfo/zone.tab").read_text(encoding="utf-8")
    countries = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        fields = line.split("\t")
        if len(fields) >= 3:
            countries[fields[2]] = fields[0]
    return countries


def country_at(lon: float, lat: float) -> tuple[str | None, str | None]:
    """(ISO country code, IANA zone) under a WGS84 point; (None, zone or None) on the open sea."""
    if not (math.isfinite(lon) and math.isfinite(lat) and -180 <= lon <= 180 and -90 <= lat <= 90):
        raise InputError(f"not a WGS84 position: lon {lon}, lat {lat}")
    zone = _timezone_finder().timezone_at(lng=float(lon), lat=float(lat))
    return (_zone_countries().get(zone) if zone else None), zone


def side_at(lon: float, lat: float) -> DrivingSide:
    """The driving side of the country under (lon, lat); right-hand on the open sea."""
    country, zone = country_at(lon, lat)
    where = f"({lon:.5f}, {lat:.5f})"
    if country is None:
        return DrivingSide("right", "location", f"the map centre {where} is in no country ({zone or 'no zone'})",
                           None, zone)
    side = "left" if country in LEFT_HAND_COUNTRIES else "right"
    return DrivingSide(side, "location", f"the map centre {where} is in {country} ({zone})", country, zone)


def choose(option: str, detected: DrivingSide | None) -> DrivingSide:
    """The side to build with: the user's ``option`` (left/right), else ``detected``, else right-hand."""
    option = check_choice(option)
    if option in SIDES:
        return DrivingSide(option, "option", f"driving_side = {option} (given)")
    if detected is not None:
        return detected
    return DrivingSide("right", "default", "no location known")


def opendrive_side(odr) -> DrivingSide:
    """The side an OpenDRIVE map's roads say (``rule``, right-hand when absent), by the majority of road length."""
    left = sum(road.length for road in odr.roads if road.rule == "LHT")
    total = sum(road.length for road in odr.roads)
    count = sum(1 for road in odr.roads if road.rule == "LHT")
    side = "left" if total > 0 and left > 0.5 * total else "right"
    if count == 0:
        why = "no road has rule=\"LHT\" (OpenDRIVE's default)"
    else:
        why = f"{count} of {len(odr.roads)} roads have rule=\"LHT\""
    return DrivingSide(side, "opendrive", why)
