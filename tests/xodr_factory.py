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


def tiled_copies(xodr_text: str, nx: int, ny: int, spacing: float) -> str:
    """A larger synthetic map: ``nx`` x ``ny`` copies of a real one side by side, ``spacing`` metres apart (so
    memory and time can be measured against map size with the real map's roads, junctions and marks).
    Every id a copy defines or references gets the copy's suffix; lane ids stay."""
    import copy
    import xml.etree.ElementTree as ET

    root = ET.fromstring(xodr_text.encode("utf-8"))
    originals = [element for element in root if element.tag in ("road", "junction", "controller")]
    for element in originals:
        root.remove(element)
    renamed = ("id", "elementId", "incomingRoad", "connectingRoad", "signalId", "controllerId")
    for i in range(nx):
        for j in range(ny):
            suffix = f"_{i}_{j}"
            for original in originals:
                element = copy.deepcopy(original)
                for node in element.iter():
                    for name in renamed:
                        if name in node.attrib and node.tag != "lane":
                            node.set(name, node.get(name) + suffix)
                    if node.tag == "road" and node.get("junction", "-1") != "-1":
                        node.set("junction", node.get("junction") + suffix)
                    if node.tag == "geometry":
                        node.set("x", repr(float(node.get("x")) + i * spacing))
                        node.set("y", repr(float(node.get("y")) + j * spacing))
                root.append(element)
    return ET.tostring(root, encoding="unicode")
