"""The reader's fast path for repeated ``<lanes>`` blocks: read each distinct block once, not once per road.

After the planViews (planview_scan.py), a region's lanes are the largest part of what the reader turns from
lxml elements into objects (region-60: 59,000 roads, about 130,000 lanes, a quarter of the load), and they
repeat: a synthetic region or a city has a few dozen kinds of road cross-section (one 3.5 m lane each way, 13.89
m/s, solid marks), written byte for byte the same for thousands of roads. The scan (``PlanViewScan``) empties
the ``<lanes>`` content of every road whose content it has seen before (its newlines kept: the lines after it
stay), and queues (line, content, layout); the reader reads each distinct content once, from the bytes, as a
fragment (``LanesRecipes``), and makes each road's lane sections and lanes from that recipe with the road's own
source lines.

Only content in the plain form is emptied (``lanes_layout``): the lane tags a converter writes, marks and
records without children, no entity, comment, CDATA, single quote, non-ASCII byte or tag over two lines; every
start tag followed by text. Then the objects the careful path makes from it depend on the bytes alone, but for
the source lines, which follow from where each start tag is: its line, or past libxml2's 16-bit line numbers
(planview_scan._BIG_LINE) the line of the next tag after it (the text that follows it ends there).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

LANES_OPEN, LANES_CLOSE = b"<lanes>", b"</lanes>"
BIG_LINE = 65535  # planview_scan._BIG_LINE: libxml2 keeps an element's line in 16 bits
# the plain form's elements by their parent's tag: what the careful path reads, nothing it would keep verbatim
_CHILDREN = {
    b"lanes": frozenset((b"laneOffset", b"laneSection")), b"laneSection": frozenset((b"left", b"center", b"right")),
    b"left": frozenset((b"lane",)), b"center": frozenset((b"lane",)), b"right": frozenset((b"lane",)),
    b"lane": frozenset(b"link width border roadMark speed access material visibility rule".split()),
    b"link": frozenset((b"predecessor", b"successor")),
}
_PARENT_TAGS = frozenset(_CHILDREN) - {b"lanes"}
# a cubic record as netconvert writes it (reader._Reader.cubic's fast path): its five numbers are the holes of
# the content's template, so that roads whose lanes differ only in widths (a junction's, a ramp's) share one
_CUBIC_RECORD = re.compile(rb'<(laneOffset s|width sOffset|border sOffset)="([^"]*)" a="([^"]*)" b="([^"]*)" '
                           rb'c="([^"]*)" d="([^"]*)"/>')
_CUBIC_TAGS = (b"<laneOffset", b"<width", b"<border")
_NUMBER_BYTES = b"0123456789.eE+-"  # all a hole's value may hold (float() decides whether it is a number)
_TAG = re.compile(rb"<(/?)([A-Za-z_][A-Za-z0-9_.:-]*)")
_VALUE = re.compile(rb'"([^"]*)"')
_REFUSED_BYTES = (b"&", b"\r", b"<!", b"<?", b"'", b"\t", b"singleSide")


@dataclass(frozen=True, slots=True)
class LanesLayout:
    """Where the start tags of a plain lanes content are, in document order: lines after the ``<lanes>`` tag's,
    of the tag itself (``tag_lines``) and of the next tag after it (``next_tag_lines``); ``newlines``: the
    content's."""

    newlines: int
    tag_lines: tuple[int, ...]
    next_tag_lines: tuple[int, ...]



def lane_line(line: int, lanes_line: int, lines: tuple[int, int]) -> int:
    """The source line lxml gives (plus the line offset: ``line`` is ``lanes_line`` with it) an element whose
    start tag is ``lines`` = (tag_lines[i], next_tag_lines[i]) of a LanesLayout after a <lanes> tag on
    ``lanes_line`` of the stream."""
    near, after = lines
    return line + (near if lanes_line + near < BIG_LINE else after)


def lanes_template(content: bytes) -> tuple[bytes, list[bytes]] | None:
    """(template, values): the content without the numbers of its cubic records, and those numbers (five a
    record, in the order of the file), or None if a number holds a byte no number may."""
    parts = _CUBIC_RECORD.split(content)  # text, tag, five numbers, text, tag, ...
    template = b"\0".join(parts[0::7]) + b"\0" + b" ".join(parts[1::7])
    del parts[0::7]
    del parts[0::6]  # the numbers
    if b"".join(parts).translate(None, _NUMBER_BYTES):
        return None
    return template, parts


def lanes_layout(content: bytes) -> LanesLayout | None:
    """The layout of a ``<lanes>`` content in the plain form (see the module's docstring), or None."""
    if not content.isascii() or any(refused in content for refused in _REFUSED_BYTES):
        return None
    if sum(content.count(tag) for tag in _CUBIC_TAGS) != len(_CUBIC_RECORD.findall(content)):
        return None  # a cubic record in another form: it would not be a hole of the template
    for value in _VALUE.findall(content):
        if b">" in value or b"\n" in value:
            return None
    if _VALUE.sub(b"", content).count(b'"'):
        return None  # a quote without its pair
    tag_lines, next_tag_lines = [], []
    line = position = 0  # the line at ``position``
    parents = [b"lanes"]
    for match in _TAG.finditer(content):
        closing, name = match.groups()
        if closing:
            if parents.pop() != name or not parents:
                return None
            continue
        end = content.find(b">", match.end())
        if end < 0 or b"\n" in content[match.start():end] or b"<" in content[match.end():end]:
            return None
        if name not in _CHILDREN[parents[-1]]:
            return None
        if content[end - 1:end] != b"/":
            if name not in _PARENT_TAGS:  # children would make a mark or a record its own, not shared
                return None
            parents.append(name)
        following = content.find(b"<", end + 1)
        if following < 0:
            following = len(content)
        if following == end + 1:
            return None  # no text after the start tag: past 65535 its line would be another element's
        line += content.count(b"\n", position, match.start())
        tag_lines.append(line)
        next_tag_lines.append(line + content.count(b"\n", match.start(), following))
        position = match.start()
    if parents != [b"lanes"] or content.count(b"<") != len(tag_lines) + content.count(b"</"):
        return None  # an element left open, or a "<" that is no tag the pattern knows
    return LanesLayout(content.count(b"\n"), tuple(tag_lines), tuple(next_tag_lines))
