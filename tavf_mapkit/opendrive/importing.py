"""An OpenDRIVE file as a build input: the build's own copy, with the driving side the user asked for.

The copy is the user's file byte for byte (line numbers in later messages stay the user's), with one repair:
comments standing before the XML declaration (a licence, as in CARLA's Town07) make a file that strict XML
parsers refuse, so the declaration is moved in front of them (the lines after it keep their numbers). When
``driving_side`` is given as left or right and some road says otherwise, every ``<road>`` gets ``rule="LHT"``
or ``rule="RHT"`` (OpenDRIVE 1.5+; right-hand when absent) and everything else is kept.
"""

from __future__ import annotations

import re
from pathlib import Path

from tavf_mapkit.drivingside import DrivingSide, choose, opendrive_side

RULES = {"left": "LHT", "right": "RHT"}
_DECLARATION = re.compile(rb"<\?xml[^>]*\?>")


def declaration_first(data: bytes) -> bytes:
    """``data`` with an XML declaration that follows comments moved to the very start (BOM kept)."""
    bom = b"\xef\xbb\xbf" if data.startswith(b"\xef\xbb\xbf") else b""
    body = data[len(bom):]
    match = _DECLARATION.search(body, 0, 1 << 16)
    if match is None or not body[: match.start()].strip():
        return data
    prolog, rest = body[: match.start()], body[match.end():]
    # the prolog's last line break moves behind the declaration, so every line after it keeps its number
    return bom + match.group() + b"\n" + prolog.rstrip(b"\r\n") + rest


def map_driving_side(odr, option: str) -> tuple[DrivingSide, bool]:
    """(the side the build drives on, whether the roads' rules must be rewritten for it)."""
    own = opendrive_side(odr)
    side = choose(option, own)
    wanted = RULES[side.side]
    rewrite = any(road.rule != wanted for road in odr.roads)
    if side.source == "option" and not rewrite:
        side = own  # the file already says so: its own reason is the better one
    return side, side.source == "option" and rewrite


def write_build_copy(source: Path, target: Path, rule: str | None) -> None:
    """Copy ``source`` to ``target``; with ``rule`` ("LHT"/"RHT"), set it on every road."""
    data = source.read_bytes()
    if rule is None:
        target.write_bytes(declaration_first(data))
        return
    from tavf_mapkit.xmlsafe import parse_safe, prepare_xml_bytes

    prepared = prepare_xml_bytes(data, str(source))
    root = parse_safe(prepared)
    for road in root.iter("{*}road"):
        road.set("rule", rule)
    from lxml import etree

    text = etree.tostring(root.getroottree(), xml_declaration=True, encoding="UTF-8")
    prolog = data[: len(data) - len(prepared.data)].removeprefix(b"\xef\xbb\xbf")
    if prolog.strip():  # comments that stood before the declaration go right after it
        declaration, _, rest = text.partition(b"\n")
        text = declaration + b"\n" + prolog.strip() + b"\n" + rest
    target.write_bytes(text)
