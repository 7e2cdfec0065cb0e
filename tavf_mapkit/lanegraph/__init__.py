"""Lane-level routing graph of an OpenDRIVE map: lanes as nodes, driving-direction edges, lane changes.

    >>> from tavf_mapkit.lanegraph import LaneGraph
    >>> graph = LaneGraph.from_opendrive(odr)                 # driving lanes only
    >>> route = graph.shortest_path(a, b)                     # [LaneKey, ...] (A*)
    >>> points, s = graph.centerline(route[0], step=1.0)      # in driving direction
"""

from tavf_mapkit.lanegraph.graph import LaneGraph, NoRouteError
from tavf_mapkit.lanegraph.index import LaneIndex, Projection
from tavf_mapkit.lanegraph.keys import LaneKey, drives_with_s

__all__ = ["LaneGraph", "LaneIndex", "LaneKey", "NoRouteError", "Projection", "drives_with_s"]
