"""ASAM OpenDRIVE core: one module per concept (geometry, reference line, lane section, lane, road, ...).

    >>> from tavf_mapkit.opendrive import load_opendrive
    >>> odr = load_opendrive("map.xodr")
    >>> road = odr.roads[0]
    >>> road.surface_point([0.0, 10.0], t=-1.75)        # (s, t) -> (x, y, z)
"""

from tavf_mapkit.opendrive.network import OpenDriveMap
from tavf_mapkit.opendrive.reader import load_opendrive, loads_opendrive

__all__ = ["OpenDriveMap", "load_opendrive", "loads_opendrive"]
