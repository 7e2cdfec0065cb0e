"""Timestamps of trace files as seconds: numbers pass through, ISO 8601 text becomes Unix time."""

from __future__ import annotations

import math
from datetime import UTC, datetime


def parse_time(text) -> float:
    """Seconds from a number or an ISO 8601 string (naive times are taken as UTC); NaN when empty/unknown."""
    if text is None:
        return math.nan
    if isinstance(text, (int, float)):
        return float(text)
    text = str(text).strip()
    if not text:
        return math.nan
    try:
        return float(text)
    except ValueError:
        pass
    try:
        moment = datetime.fromisoformat(text.replace("Z", "+00:00") if text.endswith("Z") else text)
    except ValueError:
        raise ValueError(f"not a time: {text!r}") from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.timestamp()
