"""Small synthetic OpenDRIVE documents for analytic tests."""

from __future__ import annotations


def road_xml(geometry: str, length: float, lanes: str | None = None, extra: str = "", road_id: str = "1",
             lane_offset: str = "", link: str = "") -> str:
    lanes = lanes or """
        <laneSection s="0">
          <left><lane id="1" type="driving" level="false"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
          <center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
        </laneSection>"""
    return f"""
    <road id="{road_id}" length="{length!r}" junction="-1">
      {link}
      <planView>{geometry}</planView>
      {extra}
      <lanes>{lane_offset}{lanes}</lanes>
    </road>"""


def document(*roads: str, header_extra: str = "", tail: str = "") -> str:
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<OpenDRIVE>
  <header revMajor="1" revMinor="6" name="synthetic">{header_extra}</header>
  {''.join(roads)}
  {tail}
</OpenDRIVE>
"""
