"""A LaneletMap as Lanelet2's OSM XML: nodes with lat/lon and ``ele``, ways, lanelet and regulatory relations.

Ids are positive and unique across all primitives (Lanelet2 keeps one id space): nodes 1..N, then ways, then
lanelets, then regulatory elements. Every element carries ``version="1"`` so JOSM opens the file. Tag values
come from the OpenDRIVE file (road ids, signal ids) and are escaped.
"""

from __future__ import annotations

import re
from functools import lru_cache
from xml.sax.saxutils import escape

import numpy as np

_ATTRIBUTE = {'"': "&quot;", "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"}
_STRING = np.dtypes.StringDType()


_SPECIAL = re.compile(r'[&<>"\n\r\t]')


def _text(value) -> str:
    text = str(value)
    return escape(text, _ATTRIBUTE) if _SPECIAL.search(text) else text


@lru_cache(maxsize=4096)
def _tag_block(items: tuple[tuple[str, str], ...]) -> str:
    """The <tag> lines of a tag set (ways share a few sets, so each is formatted once)."""
    return "".join(f'    <tag k="{_text(k)}" v="{_text(v)}"/>\n' for k, v in items)


def _join(*columns) -> np.ndarray:
    """Element-wise concatenation of string arrays and plain strings (numpy's variable-width strings)."""
    out = np.asarray(columns[0]).astype(_STRING)
    for column in columns[1:]:
        out = np.strings.add(
            out, np.asarray(column).astype(_STRING) if not isinstance(column, str) else column
        )
    return out


def _fixed(values: np.ndarray, digits: int) -> np.ndarray:
    """Fixed-point decimal strings of floats, through integers (numpy's %-formatting is much slower)."""
    values = np.asarray(values, dtype=float)
    scaled = np.rint(np.abs(values) * 10.0**digits).astype(np.int64)
    whole, fraction = np.divmod(scaled, 10**digits)
    sign = np.where((values < 0) & (scaled > 0), "-", "").astype(_STRING)
    return _join(sign, whole.astype(_STRING), ".", np.strings.zfill(fraction.astype(_STRING), digits))


#: nodes / ways formatted at once: a region's millions of nodes as one list of strings would cost gigabytes
_BLOCK = 200_000


def osm_text(laneletmap, lon: np.ndarray, lat: np.ndarray, comment: str = "") -> str:
    """The whole file as text; ``lon``/``lat`` (degrees) of every node."""
    return "".join(osm_chunks(laneletmap, lon, lat, comment))


def osm_chunks(laneletmap, lon: np.ndarray, lat: np.ndarray, comment: str = ""):
    """``osm_text`` piece by piece (a block of nodes or ways at a time), to be written as it comes."""
    n_nodes = len(laneletmap.nodes)
    n_ways = len(laneletmap.way_nodes)
    way_base = n_nodes + 1
    lanelet_base = way_base + n_ways
    regulatory_base = lanelet_base + len(laneletmap.lanelets)
    parts = ['<?xml version="1.0" encoding="UTF-8"?>\n', '<osm version="0.6" generator="tavf-mapkit">\n']
    if comment:
        parts.append(f"  <!-- {_text(comment).replace('--', '- -')} -->\n")
    if n_nodes:
        parts.append(
            f'  <bounds minlat="{lat.min():.10f}" minlon="{lon.min():.10f}" '
            f'maxlat="{lat.max():.10f}" maxlon="{lon.max():.10f}"/>\n'
        )
    yield "".join(parts)
    for first in range(0, n_nodes, _BLOCK):
        block = slice(first, min(first + _BLOCK, n_nodes))
        yield "".join(
            _join(
                '  <node id="',
                np.arange(block.start + 1, block.stop + 1).astype(_STRING),
                '" version="1" lat="',
                _fixed(lat[block], 10),
                '" lon="',
                _fixed(lon[block], 10),
                '">\n    <tag k="ele" v="',
                _fixed(laneletmap.nodes[block, 2], 4),
                '"/>\n  </node>\n',
            ).tolist()
        )
    for first in range(0, n_ways, _BLOCK):
        ways = laneletmap.way_nodes[first : first + _BLOCK]
        counts = np.array([len(nodes) for nodes in ways], dtype=np.int64)
        refs = _join('    <nd ref="', (np.concatenate(ways) + 1).astype(_STRING), '"/>\n').tolist()
        ends = np.cumsum(counts)
        parts = []
        for w, (start, end) in enumerate(zip(ends - counts, ends), start=first):
            parts.append(f'  <way id="{way_base + w}" version="1">\n')
            parts.extend(refs[start:end])
            parts.append(_tag_block(tuple(laneletmap.way_tags[w].items())))
            parts.append("  </way>\n")
        yield "".join(parts)
    parts = []
    for i, lanelet in enumerate(laneletmap.lanelets):
        parts.append(
            f'  <relation id="{lanelet_base + i}" version="1">\n'
            f'    <member type="way" ref="{way_base + lanelet["left"]}" role="left"/>\n'
            f'    <member type="way" ref="{way_base + lanelet["right"]}" role="right"/>\n'
        )
        if "centerline" in lanelet:
            parts.append(
                f'    <member type="way" ref="{way_base + lanelet["centerline"]}" role="centerline"/>\n'
            )
        parts.extend(
            f'    <member type="relation" ref="{regulatory_base + r}" role="regulatory_element"/>\n'
            for r in lanelet["regulatory"]
        )
        parts.append(_tag_block(tuple(lanelet["tags"].items())))
        parts.append("  </relation>\n")
    for i, element in enumerate(laneletmap.regulatory):
        parts.append(f'  <relation id="{regulatory_base + i}" version="1">\n')
        parts.extend(
            f'    <member type="{kind}" ref="{way_base + index}" role="{role}"/>\n'
            for kind, index, role in element["members"]
        )
        parts.append(_tag_block(tuple(element["tags"].items())))
        parts.append("  </relation>\n")
    parts.append("</osm>\n")
    yield "".join(parts)
