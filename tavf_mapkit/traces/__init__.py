"""GNSS traces from files: GPX, GeoJSON, CSV, the JSON ride format of the TAVF B4 recording, ROS 1/2 bags.

    >>> from tavf_mapkit.traces import read_trace
    >>> trace = read_trace("ride.gpx")                      # Trace: lat, lon, t, alt, speed, heading, accuracy
    >>> x, y = trace.local_xy(odr.georeference)             # into a map's local coordinates
"""

from tavf_mapkit.traces.reader import TRACE_FORMATS, read_trace
from tavf_mapkit.traces.trace import Trace

__all__ = ["TRACE_FORMATS", "Trace", "read_trace"]
