"""A small clean network for the validator's tests: two plain roads, a junction with one connecting road, a third
plain road; georeferenced, lane links in both directions. ``network_text(**changes)`` injects faults."""

from __future__ import annotations

from tests.xodr_factory import document, road_xml

GEOREFERENCE = "<geoReference><![CDATA[+proj=tmerc +lat_0=53.55 +lon_0=9.99 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 " \
               "+units=m +no_defs]]></geoReference>"
HEADER_BOUNDS = 'west="0" south="-3" east="200" north="3.5"'


def lanes(right_width: str = '<width sOffset="0" a="3" b="0" c="0" d="0"/>', left_links: str = "",
          right_links: str = "") -> str:
    return f"""
        <laneSection s="0">
          <left><lane id="1" type="driving" level="false">{left_links}
            <width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
          <center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false">{right_links}
            {right_width}</lane></right>
        </laneSection>"""


def link(predecessor: str = "", successor: str = "") -> str:
    return f"<link>{predecessor}{successor}</link>"


def lane_link(predecessor: int | None = None, successor: int | None = None) -> str:
    inner = (f'<predecessor id="{predecessor}"/>' if predecessor is not None else "") + \
            (f'<successor id="{successor}"/>' if successor is not None else "")
    return f"<link>{inner}</link>"


def line(s: float, x: float, y: float, length: float, hdg: float = 0.0) -> str:
    return f'<geometry s="{s!r}" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}"><line/></geometry>'


def network_text(road1_geometry: str | None = None, road2_successor: str | None = None,
                 road1_right_successor: int = -1, road4_right_width: str | None = None,
                 header_extra: str | None = None, with_junction: bool = True, header_bounds: str = HEADER_BOUNDS,
                 shift_x: float = 0.0) -> str:
    road1 = road_xml(
        road1_geometry or line(0.0, 0.0 + shift_x, 0.0, 100.0), 100.0, road_id="1",
        link=link(successor='<successor elementType="road" elementId="2" contactPoint="start"/>'),
        lanes=lanes(left_links=lane_link(predecessor=1), right_links=lane_link(successor=road1_right_successor)))
    road2 = road_xml(
        line(0.0, 100.0 + shift_x, 0.0, 50.0), 50.0, road_id="2",
        link=link('<predecessor elementType="road" elementId="1" contactPoint="end"/>',
                  road2_successor or '<successor elementType="junction" elementId="10"/>'),
        lanes=lanes(left_links=lane_link(successor=1), right_links=lane_link(predecessor=-1)))
    road3 = road_xml(
        line(0.0, 150.0 + shift_x, 0.0, 20.0), 20.0, road_id="3",
        link=link('<predecessor elementType="road" elementId="2" contactPoint="end"/>',
                  '<successor elementType="road" elementId="4" contactPoint="start"/>'),
        lanes=lanes(left_links=lane_link(predecessor=1, successor=1),
                    right_links=lane_link(predecessor=-1, successor=-1))).replace('junction="-1"', 'junction="10"')
    road4 = road_xml(
        line(0.0, 170.0 + shift_x, 0.0, 30.0), 30.0, road_id="4",
        link=link('<predecessor elementType="junction" elementId="10"/>'),
        lanes=lanes(right_width=road4_right_width or '<width sOffset="0" a="3" b="0" c="0" d="0"/>'))
    junction = """
  <junction id="10" name="j">
    <connection id="0" incomingRoad="2" connectingRoad="3" contactPoint="start"><laneLink from="-1" to="-1"/></connection>
    <connection id="1" incomingRoad="4" connectingRoad="3" contactPoint="end"><laneLink from="1" to="1"/></connection>
  </junction>""" if with_junction else ""
    text = document(road1, road2, road3, road4, header_extra=GEOREFERENCE if header_extra is None else header_extra,
                    tail=junction)
    return text.replace('name="synthetic">', f'name="synthetic" {header_bounds}>')


def write_network(folder, name: str = "net.xodr", **changes):
    path = folder / name
    path.write_text(network_text(**changes))
    return path
