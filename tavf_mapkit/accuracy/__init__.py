"""Accuracy of built maps: map matching of GNSS traces, comparison with a reference network, the check stage.

    >>> from tavf_mapkit.accuracy.matching import match_trace
    >>> result = match_trace(odr, read_trace("ride.json"))
    >>> result.stats()["median_m"], result.lane_route[:3]
"""
