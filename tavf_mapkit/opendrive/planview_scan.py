"""The reader's fast path for plain planViews: read from the bytes before the XML parser sees them.

A region's OpenDRIVE is mostly planView (region-32: 560,000 <geometry> of 900,000 elements; netconvert writes
curves as runs of short arcs), and reading it element by element through lxml -- a Python object per element,
per attribute list, per number -- was about half of the load. ``PlanViewScan`` wraps the stream the parser
reads: each ``<planView>`` whose content is in the plain form of a line or an arc per geometry, exactly the
attributes s, x, y, hdg, length (in this order, double quotes, every number finite, a positive length: what the
reader's own hot path accepts, ``reader._Reader.plan_view``) is converted here, a chunk at a time with a few
array operations, and handed on to the parser emptied (its newlines kept, so every line number after it stays
the same). Anything else -- comments, other kinds, other attributes, entities, odd whitespace -- is left to the
parser and the careful path, byte for byte.

The reader pairs each emptied planView with the road it belongs to by its line (``take``); one it cannot pair
(a planView in a comment, in userData, not a road's first) makes it read the file again without this scan.
"""

from __future__ import annotations

import re
from collections import deque

import numpy as np

from tavf_mapkit.opendrive.decimal_columns import decimals_at
from tavf_mapkit.opendrive.geometry import NARROW_COLUMNS, GeometryKind
from tavf_mapkit.opendrive.lanes_scan import (
    LANES_CLOSE,
    LANES_OPEN,
    LanesLayout,
    lanes_layout,
    lanes_template,
)

CHUNK_BYTES = 1 << 20  # read this much at a time: array operations over hundreds of planViews each
_OPEN, _CLOSE = b"<planView>", b"</planView>"
_LONGEST_HELD = 64 << 20
_LANES_CONTENTS_KEPT = 1 << 15  # distinct lanes contents whose template is kept (about 1 kB each): bounded memory
_W = rb"(?:[ \t\n]|\r\n)*"  # XML white space; a lone CR would count lines differently than libxml2: refused
# one code per text between two double quotes of a planView's content (the attribute values are between them)
_TOKEN_KINDS = [
    (b"S", rb"" + _W + rb"<geometry[ \t]+s="),  # the first geometry's start tag
    (b"x", rb"[ \t]+x="), (b"y", rb"[ \t]+y="), (b"h", rb"[ \t]+hdg="), (b"l", rb"[ \t]+length="),
    (b"a", rb"[ \t]*>" + _W + rb"<arc[ \t]+curvature="),  # an arc's shape
    (b"n", rb"[ \t]*/>" + _W + rb"</geometry>" + _W + rb"<geometry[ \t]+s="),  # after an arc: the next geometry
    (b"e", rb"[ \t]*/>" + _W + rb"</geometry>" + _W),  # after the last arc
    (b"N", rb"[ \t]*>" + _W + rb"<line[ \t]*/>" + _W + rb"</geometry>" + _W + rb"<geometry[ \t]+s="),  # a line
    (b"E", rb"[ \t]*>" + _W + rb"<line[ \t]*/>" + _W + rb"</geometry>" + _W),  # the last one a line
]
_TOKEN_PATTERNS = [(code, re.compile(pattern)) for code, pattern in _TOKEN_KINDS]
_PLAIN_CONTENT = re.compile(rb"S(?:xyhl(?:an|N))*xyhl(?:ae|E)")  # the codes of a plain planView's content
_SPACES = (b" ", b"\t", b"\n")
_QUOTE = ord('"')
_LONGEST_TEXT = 128  # bytes of a text between values (indentation and tags) the array path takes; longer: tokens
_HASH_FACTORS = np.random.default_rng(15).integers(1, 2**63, _LONGEST_TEXT // 8, dtype=np.uint64) | np.uint64(1)
_NUMBER_BYTES = b"0123456789.eE+-"  # all a plain value may hold; float() decides whether it is a number
_OPENERS = np.frombuffer(b"SnN", dtype=np.uint8)  # tokens that end with a geometry's start tag
_AFTER_LENGTH_CODES = b"aNE"  # the token after @length: an arc, or a line
_AFTER_LENGTH = np.frombuffer(_AFTER_LENGTH_CODES, dtype=np.uint8)
_ROLE = {ord("x"): 1, ord("y"): 2, ord("h"): 3, ord("l"): 4, ord("a"): 6}  # a value's column by the text before it
# the same as tables by code (one gather per chunk, not a pass per code)
_COLUMN_OF_CODE = np.zeros(256, dtype=np.int64)  # s (0) after S, n or N
_COLUMN_OF_CODE[list(_ROLE)] = list(_ROLE.values())
_IS_OPENER = np.isin(np.arange(256), _OPENERS)
_IS_AFTER_LENGTH = np.isin(np.arange(256), _AFTER_LENGTH)
_LINE, _ARC = float(GeometryKind.LINE), float(GeometryKind.ARC)


class _TokenCodes(dict):
    """token bytes -> its code; ``newlines`` and ``before_tag`` (-1: no text before it) of each token looked up
    so far. A file's tokens are a few distinct texts (its indentation), looked up millions of times."""

    def __init__(self):
        super().__init__()
        self.newlines: dict[bytes, int] = {}
        self.before_tag: dict[bytes, int] = {}

    def __missing__(self, token: bytes) -> int:
        code = next((code for code, pattern in _TOKEN_PATTERNS if pattern.fullmatch(token)), b"?")
        tag = token.find(b"<")
        self.before_tag[token] = token.count(b"\n", 0, tag) if tag > token.find(b">") + 1 else -1
        self.newlines[token] = token.count(b"\n")
        found = self[token] = code[0]
        return found


# libxml2 keeps an element's line in 16 bits: from this line on, lxml's ``sourceline`` of an element is that of
# its first child (xmlGetLineNo), for a text the line the text ends on. The lines given here are what the parser
# would give for the same elements (the reader's careful path reads them from it).
_BIG_LINE = 65535


class PlanViewScan:
    """A binary stream (``read``) of the document with its plain planViews emptied; ``blocks`` holds, in the
    order of the file, (line of the <planView> tag in the stream, narrow rows, source lines) of each emptied one."""

    def __init__(self, stream, line_offset: int = 0):
        self.stream = stream
        self.line_offset = line_offset
        self.blocks: deque = deque()
        self._held = b""  # read, not yet scanned: a planView that may continue in the next chunk
        self._held_line = 1  # the line _held starts on
        self._ready = b""
        self._ready_at = 0
        self._last_byte = b""  # the last byte handed on
        self._ended = False
        self._codes = _TokenCodes()
        # (line of the <lanes> tag, content, (template, values), its LanesLayout) of each emptied one
        self.lanes_blocks: deque = deque()
        self._lanes_seen: set[int] = set()  # hashes of the lanes templates seen (a collision only empties one more)
        self._lanes_layouts: dict[bytes, LanesLayout | None] = {}
        self._lanes_templates: dict[bytes, tuple | None] = {}  # lanes_template of the first contents, by content

    def read(self, size: int = -1) -> bytes:
        while len(self._ready) - self._ready_at < max(size, 1) and not self._ended:
            self._scan_more()
        if size < 0:
            size = len(self._ready) - self._ready_at
        out = self._ready[self._ready_at:self._ready_at + size]
        self._ready_at += len(out)
        return out

    def take(self, line: int, text: str | None):
        """(narrow rows, source lines, whether sorted by s) of the emptied planView whose tag is on this line of the stream and whose
        text is ``text``, or None when the next emptied one is further on; raises PlanViewMismatch if one was
        passed by (not a road's planView) or this one is not it. Only planViews with a newline inside are
        emptied, so two on one line cannot be taken for each other: their texts differ."""
        blocks = self.blocks
        if not blocks or blocks[0][0] > line:
            return None
        tag_line, rows, lines, newlines, in_order = blocks.popleft()
        # an emptied planView's first child is its text, which ends newlines further on (see _BIG_LINE)
        if (tag_line if tag_line < _BIG_LINE else tag_line + newlines) != line or text != "\n" * newlines:
            raise PlanViewMismatch
        return rows, lines, in_order

    def take_lanes(self, line: int, text: str | None):
        """(content, (template, values), layout, line of the tag in the stream) of the emptied <lanes> whose
        element lxml puts on
        this line with this text, or None; raises PlanViewMismatch as ``take`` does."""
        blocks = self.lanes_blocks
        if not blocks or blocks[0][0] > line:
            return None
        tag_line, content, template, layout = blocks.popleft()
        newlines = layout.newlines
        if (tag_line if tag_line < _BIG_LINE else tag_line + newlines) != line or text != "\n" * newlines:
            raise PlanViewMismatch
        return content, template, layout, tag_line

    def _scan_more(self) -> None:
        more = self.stream.read(CHUNK_BYTES)
        data = self._held + more
        if not more:
            self._ended = True
            self._emit(data, len(data), [])
            return
        spans, cut, position = [], len(data), 0
        while True:
            start = data.find(_OPEN, position)
            if start < 0:
                cut = max(position, len(data) - len(_OPEN) + 1)  # the start of a tag may be at the chunk's end
                break
            close = data.find(_CLOSE, start)
            if close < 0:
                # a planView that may end in the next chunk; one that never ends (a comment's, a broken file)
                # is handed on as it is once it is this long, not searched again and again
                cut = start if len(data) - start < _LONGEST_HELD else len(data)
                break
            spans.append((start, close))
            position = close + len(_CLOSE)
        cut = self._lanes_cut(data, cut)
        self._emit(data, cut, [span for span in spans if span[1] < cut])

    def _lanes_cut(self, data: bytes, cut: int) -> int:
        """``cut``, or the start of a <lanes> before it that may end in the next chunk (held back with it)."""
        start = data.rfind(LANES_OPEN, 0, cut + len(LANES_OPEN) - 1)  # its tag may be cut in two, too
        if start < 0 or start >= cut or data.find(LANES_CLOSE, start, cut) >= 0 or cut - start >= _LONGEST_HELD:
            return cut
        return start

    def _emit(self, data: bytes, cut: int, spans: list) -> None:
        """Hand on data[:cut] with the plain planViews among ``spans`` emptied; keep the rest for later."""
        emptied = [(start + len(_OPEN), close, newlines) for start, close, newlines in self._convert(data, spans)]
        lanes = self._empty_lanes(data, cut, spans)
        if lanes:
            emptied = sorted(emptied + lanes)
        pieces, position = [], 0
        for start, close, newlines in emptied:
            pieces.append(data[position:start])
            pieces.append(b"\n" * newlines)
            position = close
        pieces.append(data[position:cut])
        self._ready = self._ready[self._ready_at:] + b"".join(pieces)
        self._ready_at = 0
        self._held_line += data.count(b"\n", 0, cut)
        if cut:
            self._last_byte = data[cut - 1:cut]
        self._held = data[cut:]

    def _empty_lanes(self, data: bytes, cut: int, plan_views: list) -> list:
        """Queue the <lanes> blocks in data[:cut] in the plain form whose template was seen before
        (lanes_scan.py); the (content start, end, newlines) of those to empty. They are looked for between the
        ``plan_views`` (start, end) only: those are most of the bytes, and a planView holds no road's lanes."""
        emptied, seen, layouts, templates = [], self._lanes_seen, self._lanes_layouts, self._lanes_templates
        line, lines_at = self._held_line, 0
        gaps = iter(zip([0] + [close for _, close in plan_views], [start for start, _ in plan_views] + [cut]))
        position, gap_end = next(gaps)
        while True:
            start = data.find(LANES_OPEN, position, gap_end)
            if start < 0:
                gap = next(gaps, None)
                if gap is None:
                    return emptied
                position, gap_end = max(gap[0], position), gap[1]  # (a lanes' end may be past the gap's start)
                continue
            content_start = start + len(LANES_OPEN)
            close = data.find(LANES_CLOSE, content_start, cut)
            if close < 0:
                return emptied
            position = close + len(LANES_CLOSE)
            content = data[content_start:close]
            template = templates.get(content, False)
            if template is False:
                template = lanes_template(content)
                if len(templates) < _LANES_CONTENTS_KEPT:
                    templates[content] = template
            if template is None:
                continue
            key = hash(template[0])
            if key not in seen:  # a first: the parser reads it (a region's templates mostly repeat; a city's too)
                seen.add(key)
                continue
            layout = layouts.get(template[0], False)
            if layout is False:
                layout = layouts[template[0]] = lanes_layout(content)
            if layout is None or not layout.newlines or (data[start - 1:start] if start else self._last_byte) not in _SPACES:
                continue  # (not after white space: it may be a first child, whose line would be its own child's)
            line += data.count(b"\n", lines_at, start)
            lines_at = start
            self.lanes_blocks.append((line, content, template, layout))
            emptied.append((content_start, close, layout.newlines))

    def _convert(self, data: bytes, spans: list) -> list:
        """Queue the rows of the plain planViews among ``spans``; the spans of those queued."""
        if not spans:
            return []
        emptied = self._convert_arrays(data, spans)
        return self._convert_tokens(data, spans) if emptied is None else emptied

    def _convert_arrays(self, data: bytes, spans: list) -> list | None:
        """``_convert`` without a Python object per token: the quotes, texts and values found with array
        operations over the chunk's bytes, a text's code looked up once per distinct text. None where this
        cannot decide (a long text, two texts of one hash): ``_convert_tokens``."""
        buffer = np.frombuffer(data + bytes(_LONGEST_TEXT), dtype=np.uint8)  # zeros: every window is whole
        windows = np.lib.stride_tricks.sliding_window_view(buffer, _LONGEST_TEXT)
        span_array = np.array(spans, dtype=np.int64).reshape(-1, 2)
        starts, closes = span_array[:, 0] + len(_OPEN), span_array[:, 1]
        quotes = np.flatnonzero(buffer == _QUOTE)
        first_quote, end_quote = np.searchsorted(quotes, starts), np.searchsorted(quotes, closes)
        quote_counts = end_quote - first_quote
        if np.any(quote_counts % 2) or not np.all(quote_counts):
            return None  # an odd quote: not an attribute value as the plain form writes it
        value_counts = quote_counts // 2
        token_counts = value_counts + 1
        quote_index = _ranges(first_quote, quote_counts)
        opening, closing = quotes[quote_index[0::2]], quotes[quote_index[1::2]]
        # texts: from a block's start or after a value's closing quote, to the next opening quote or the block's end
        block_of_value = np.repeat(np.arange(len(spans)), value_counts)
        first_value = np.cumsum(value_counts) - value_counts
        text_starts = np.insert(closing + 1, first_value, starts)
        text_ends = np.insert(opening, first_value + value_counts, closes)
        text_lengths = text_ends - text_starts
        value_lengths = closing - opening - 1
        if text_lengths.max() > _LONGEST_TEXT:
            return None
        distinct = _distinct_texts(windows, text_starts, text_lengths)
        if distinct is None:
            return None
        first, inverse = distinct
        codes_of = self._codes
        distinct_texts = [data[start:end] for start, end in zip(text_starts[first].tolist(), text_ends[first].tolist())]
        codes = np.array([codes_of[text] for text in distinct_texts], dtype=np.uint8)[inverse]
        newlines = np.array([codes_of.newlines[text] for text in distinct_texts], dtype=np.int64)[inverse]
        before_tag = np.array([codes_of.before_tag[text] for text in distinct_texts], dtype=np.int64)[inverse]
        numbers, bad_value = self._numbers(data, buffer, closing, value_lengths)
        bad_blocks = np.bincount(block_of_value[bad_value], minlength=len(spans)) if bad_value.any() else None
        code_bytes, kept, keep_block = codes.tobytes(), [], np.zeros(len(spans), dtype=bool)
        first_token = (np.cumsum(token_counts) - token_counts).tolist()
        for index, ((start, close), token, count) in enumerate(zip(spans, first_token, token_counts.tolist())):
            if ((bad_blocks is None or not bad_blocks[index])
                    and _PLAIN_CONTENT.fullmatch(code_bytes, token, token + count)
                    and (data[start - 1:start] if start else self._last_byte) in _SPACES):
                kept.append((start, close, count))
                keep_block[index] = True
        if not kept:
            return []
        keep_token, keep_value = np.repeat(keep_block, token_counts), np.repeat(keep_block, value_counts)
        return self._queue(data, kept, codes[keep_token].tobytes(), newlines[keep_token], before_tag[keep_token],
                           numbers[keep_value])

    @staticmethod
    def _numbers(data: bytes, buffer: np.ndarray, ends: np.ndarray, lengths: np.ndarray) -> tuple:
        """(numbers, bad) of the values at buffer[end - length:end]: bad where a value is empty, holds a byte
        a plain value may not (_NUMBER_BYTES) or is no number to float() ("1e5e5"): its planView is left to
        the parser and the careful path, which names it."""
        numbers, read = decimals_at(buffer, ends, lengths)
        bad = np.zeros(len(numbers), dtype=bool)
        for index in np.flatnonzero(~read).tolist():  # an exponent, a long value, a broken one: rare
            text = data[ends[index] - lengths[index]:ends[index]]
            try:
                numbers[index] = float(text)
            except ValueError:
                bad[index] = True
            bad[index] |= not text or bool(text.translate(None, _NUMBER_BYTES))
        return numbers, bad

    def _convert_tokens(self, data: bytes, spans: list) -> list:
        """``_convert`` token by token (the texts and values as bytes objects)."""
        code_of = self._codes.__getitem__
        kept, token_codes, texts_kept, values = [], [], [], []
        for start, close in spans:
            tokens = data[start + len(_OPEN):close].split(b'"')
            texts = tokens[0::2]
            numbers = tokens[1::2]
            codes = bytes(map(code_of, texts))
            if (not _PLAIN_CONTENT.fullmatch(codes) or b"" in numbers
                    or b"".join(numbers).translate(None, _NUMBER_BYTES)
                    or (data[start - 1:start] if start else self._last_byte) not in _SPACES):
                # (not after white space: it may be a first child, whose line would be its own child's: _BIG_LINE)
                continue
            kept.append((start, close, len(texts)))
            token_codes.append(codes)
            texts_kept += texts
            values += numbers
        if not kept:
            return []
        try:
            numbers = np.array(values).astype(np.float64)
        except ValueError:  # e.g. "1e5e5": let the careful path name it, block by block
            return self._convert_each(data, spans) if len(spans) > 1 else []
        if not texts_kept:
            return []
        token_newlines = np.fromiter(map(self._codes.newlines.__getitem__, texts_kept), np.int64, len(texts_kept))
        before_tag = np.fromiter(map(self._codes.before_tag.__getitem__, texts_kept), np.int64, len(texts_kept))
        return self._queue(data, kept, b"".join(token_codes), token_newlines, before_tag, numbers)

    def _convert_each(self, data: bytes, spans: list) -> list:
        emptied = []
        for span in spans:
            emptied += self._convert_tokens(data, [span])
        return emptied

    def _queue(self, data: bytes, kept: list, codes: bytes, token_newlines: np.ndarray, before_tag: np.ndarray,
               numbers: np.ndarray) -> list:
        codes = np.frombuffer(codes, dtype=np.uint8)
        token_counts = np.array([count for _, _, count in kept], dtype=np.int64)
        block_of_token = np.repeat(np.arange(len(kept)), token_counts)
        # a value follows each text but a planView's last: its column is the code of the text before it
        last_token = np.cumsum(token_counts) - 1
        value_codes = np.delete(codes, last_token)
        columns = _COLUMN_OF_CODE[value_codes]
        opener = _IS_OPENER[codes]
        count = int(opener.sum())
        rows = np.zeros((count, NARROW_COLUMNS))
        geometry_of_value = np.cumsum(_IS_OPENER[value_codes]) - 1
        rows[geometry_of_value, columns] = numbers
        after_length = _IS_AFTER_LENGTH[codes]
        is_arc = codes[after_length] == ord("a")
        shape_newlines = before_tag[after_length]
        rows[:, 5] = np.where(is_arc, _ARC, _LINE)
        # source lines: the stream's line at each <planView>, then the newlines of the texts up to each geometry
        newlines = np.cumsum(token_newlines)
        first_token = last_token - token_counts + 1
        tag_lines = np.empty(len(kept), dtype=np.int64)
        position, line = 0, self._held_line
        for index, (start, _, _) in enumerate(kept):
            line += data.count(b"\n", position, start)
            tag_lines[index] = line
            position = start
        before_block = newlines[first_token] - token_newlines[first_token]
        lines = (newlines + (tag_lines - before_block)[block_of_token])[opener]
        big = lines >= _BIG_LINE  # the line of the geometry's first child: the text before its <arc> or <line>
        lines = np.where(big, lines + shape_newlines, lines) + self.line_offset
        geometry_counts = np.bincount(block_of_token[opener], minlength=len(kept))
        # what the reader's hot path takes: every number finite and a positive length; others go to the parser
        bad = ~np.isfinite(rows).all(axis=1) | ~(rows[:, 4] > 0.0) | (big & (shape_newlines < 0))
        bad_blocks = np.bincount(block_of_token[opener][bad], minlength=len(kept)) if bad.any() else None
        block_newlines = np.add.reduceat(token_newlines, first_token).tolist()
        block_of_geometry = block_of_token[opener]
        backwards = np.flatnonzero((rows[1:, 0] < rows[:-1, 0]) & (block_of_geometry[1:] == block_of_geometry[:-1]))
        in_order = np.ones(len(kept), dtype=bool)
        in_order[block_of_geometry[backwards]] = False
        in_order = in_order.tolist()
        emptied, first = [], 0
        for index, ((start, close, _), geometries) in enumerate(zip(kept, geometry_counts.tolist())):
            end = first + geometries
            if (bad_blocks is None or not bad_blocks[index]) and block_newlines[index]:
                self.blocks.append((int(tag_lines[index]), rows[first:end], lines[first:end].astype(np.int32),
                                    block_newlines[index], in_order[index]))
                emptied.append((start, close, block_newlines[index]))
            first = end
        return emptied


def _distinct_texts(windows: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> tuple | None:
    """(first, inverse): the index of one text of each distinct content, and for each text the number of its
    content among those; None if two different texts share a hash. Texts are taken in classes of width (the
    short ones -- " x=", " hdg=" -- are over half of them) so that each is padded to its class's width, not the
    longest's; one of at most 7 bytes is its own key (its bytes and its length in one word)."""
    firsts, inverse, distinct = [], np.empty(len(starts), dtype=np.int64), 0
    narrower = -1
    for width in _TEXT_WIDTHS:
        rows = np.flatnonzero((lengths > narrower) & (lengths <= width))
        narrower = width
        if not len(rows):
            continue
        class_lengths = lengths[rows]
        texts = _padded(windows, starts[rows], class_lengths, -(-width // 8) * 8)
        if width < 8:  # its bytes, then its length in the last byte: the word says the text exactly
            texts[:, 7] = class_lengths
        texts = texts.view(np.uint64)
        if width < 8:
            key = texts[:, 0]
        else:  # a hash (wrapping arithmetic), then every text compared with the first of its hash
            key = texts @ _HASH_FACTORS[:width // 8] + class_lengths.astype(np.uint64)
        _, first, class_inverse = np.unique(key, return_index=True, return_inverse=True)
        class_inverse = class_inverse.reshape(-1)
        if width >= 8 and not (np.array_equal(texts, texts[first][class_inverse])
                               and np.array_equal(class_lengths, class_lengths[first][class_inverse])):
            return None
        firsts.append(rows[first])
        inverse[rows] = class_inverse + distinct
        distinct += len(first)
    return np.concatenate(firsts), inverse


_TEXT_WIDTHS = (7, 16, 32, 64, _LONGEST_TEXT)  # bytes: the classes of texts by length (_distinct_texts)


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The indices starts[0] .. starts[0] + counts[0] - 1, then those of the next range, ..., as one array."""
    total = int(counts.sum())
    offsets = np.cumsum(counts) - counts
    return np.arange(total) - np.repeat(offsets - starts, counts)


def _padded(windows: np.ndarray, starts: np.ndarray, lengths: np.ndarray, width: int) -> np.ndarray:
    """(n, width) uint8: the bytes at start .. start + length - 1 of each, zeros after them; ``windows``: a
    sliding window view of the bytes (at least ``width`` wide, zeros after the data)."""
    rows = windows[starts, :width]
    rows *= np.arange(width, dtype=np.uint8) < lengths.astype(np.uint8)[:, None]  # bytes, not int64: 2x faster
    return rows


class PlanViewMismatch(Exception):
    """An emptied planView the reader did not read as a road's planView: read the file again without the scan."""
