"""What a loaded map costs per road: a city has 150,000 roads and the whole build must stay within 2 GB, so the
model shares what repeats (attribute dicts, short numbers) and keeps no per-record overhead it does not need."""

from __future__ import annotations

import gc
import tracemalloc

from tavf_mapkit.opendrive import loads_opendrive
from tavf_mapkit.opendrive.writer import to_xml
from tests.test_geometry_rows import _map_xml

#: traced bytes per road of _map_xml's roads (one driving lane with a width and, on the centre lane, nothing;
#: 1-4 lines and arcs): 3,226 before the model shared its attribute dicts and slotted its records, 2,310 after
BYTES_PER_ROAD = 2_600


def test_a_loaded_road_costs_what_it_holds():
    xml = _map_xml(2000)
    loads_opendrive(_map_xml(3))  # imports and first-use caches are not the map's
    gc.collect()
    tracemalloc.start()
    try:
        odr = loads_opendrive(xml)
        gc.collect()
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(odr.roads) == 2000
    assert held / len(odr.roads) < BYTES_PER_ROAD, held / len(odr.roads)


def test_lanes_with_the_same_attributes_share_one_dict_and_write_back_the_same():
    xml = _map_xml(50)
    odr = loads_opendrive(xml)
    lanes = [lane for road in odr.roads for section in road.lane_sections for lane in section.lanes]
    driving = [lane for lane in lanes if lane.id == -1]
    assert len(driving) == 50 and len({id(lane.attrib) for lane in driving}) == 1
    assert driving[0].attrib == {"id": "-1", "type": "driving"}
    # the shared dicts write each lane as it was, and the file read back writes the same bytes again
    written = to_xml(odr)
    assert written.count(b'<lane id="-1" type="driving" level="false">') == 50
    assert to_xml(loads_opendrive(written)) == written
