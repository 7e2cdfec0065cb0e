"""Decimal numbers parsed in bulk with array operations, bit for bit what ``float()`` gives.

Python's ``float()`` (and numpy's ``astype(float)`` of byte strings, which calls the same correctly rounding
parser one number at a time) costs about 500 ns for the 16-17 digit numbers netconvert writes, and a region's
planViews hold tens of millions of them. Here all numbers of a buffer are read at once. Each is taken
right-aligned in 24 bytes (three 64-bit words, eight digits each read with a few multiplications: the SWAR
method of simdjson), as ``[sign] digits [. digits]``: an integer M below 2**64 over 10**f. Then
- M <= 2**53 and f <= 22: M and 10**f are exact doubles and one IEEE division rounds correctly (Clinger's
  fast path);
- larger M (17-19 digits): the division in x87 extended precision (64-bit mantissa: M and 10**f, f <= 27, are
  exact) rounds once to 64 bits, the conversion to a double once more. Two roundings differ from one only when
  the 64-bit quotient lies exactly halfway between two doubles: those (about one in 2,000) go to float().
Anything else -- an exponent, a second dot, more than 24 bytes, a platform whose long double is not the x87
format -- goes to numpy's ``astype(float)`` as before, with its ValueError for what is not a number.
"""

from __future__ import annotations

import sys

import numpy as np

_WIDTH = 24  # bytes of a number taken on the fast path: three words of eight digits
_ZERO, _DOT, _MINUS, _PLUS = (ord(c) for c in "0.-+")
_CLINGER_MANTISSA = np.uint64(2**53)
_CLINGER_EXPONENT = 22  # 10**22 is the largest power of ten that is an exact double
_POW10_DOUBLE = np.array([10.0**k for k in range(_WIDTH)])
_LONGEST_SPLIT = 18  # fractions this long or shorter are split off with uint64 arithmetic (10**(f+1) < 2**64)
_POW10_U64 = np.array([10**k for k in range(_LONGEST_SPLIT + 2)], dtype=np.uint64)
_EXTENDED = (np.finfo(np.longdouble).nmant == 63 and np.dtype(np.longdouble).itemsize >= 10
             and sys.byteorder == "little")
_EXTENDED_EXPONENT = 27  # 5**27 < 2**64: 10**27 is exact with a 64-bit mantissa
_POW10_EXTENDED = (np.array([10**k for k in range(_WIDTH)], dtype=object).astype(np.longdouble)
                   if _EXTENDED else None)
_HALFWAY_BITS, _HALFWAY = np.uint64(0x7FF), np.uint64(0x400)  # the 11 bits below a double's 53 in a 64-bit mantissa
_U = np.uint64
_HIGH_NIBBLES, _SIX, _THREES = _U(0xF0F0F0F0F0F0F0F0), _U(0x0606060606060606), _U(0x3333333333333333)
_SHIFT_4, _SHIFT_8, _SHIFT_16, _SHIFT_32 = _U(4), _U(8), _U(16), _U(32)
_ASCII_ZEROS = _U(0x3030303030303030)
_FILL = np.array([(1 << (8 * k)) - 1 for k in range(9)], dtype=np.uint64)  # the lowest k bytes of a word
_WORD_STARTS = np.array([0, 8, 16], dtype=np.int64)
# the three words' masks of the lowest k bytes of 24 (k = 0 .. 24): one row taken per number (a 2-D fancy index
# of _FILL costs twenty times as much)
_FILL_ROWS = _FILL[np.minimum(np.maximum(np.arange(_WIDTH + 1)[:, None] - _WORD_STARTS, 0), 8)]
_1E8, _1E16 = np.uint64(10**8), np.uint64(10**16)
_LARGEST_TOP_GROUP = np.uint64(1843)  # G0 * 10**16 + (10**16 - 1) < 2**64 up to this top group


def decimals_at(buffer: np.ndarray, ends: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(values, read) of the numbers written in buffer[end - length:end], one per (end, length) -- ``buffer``
    uint8. Where ``read``, the value is bit for bit ``float()``'s of those bytes; the others (an exponent, more
    than 24 bytes, no number at all) are NaN here: what to do with them is the caller's."""
    count = len(ends)
    out = np.full(count, np.nan)
    if not count:
        return out, np.zeros(0, dtype=bool)
    ends = np.asarray(ends, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    if ends.min() < _WIDTH:  # room for the window before each number
        buffer, ends = np.concatenate([np.zeros(_WIDTH, dtype=np.uint8), buffer]), ends + _WIDTH
    rows = np.lib.stride_tricks.sliding_window_view(buffer, _WIDTH)[ends - _WIDTH]  # right-aligned, a copy
    starts = ends - lengths
    first = buffer[starts]
    signed = (first == _MINUS) | (first == _PLUS)
    # the bytes before the number (and its sign) become "0"s, which change nothing; a word at a time
    before = _WIDTH - lengths + signed
    fill = _FILL_ROWS.take(np.clip(before, 0, _WIDTH), axis=0)  # (before < 0: too long for the fast path)
    words = (rows.view(np.uint64) & ~fill) | (fill & _ASCII_ZEROS)
    dot_words = (words.view(np.uint8) == _DOT).view(np.uint64)  # a byte 1 where a dot is
    dot_count = ((dot_words[:, 0] + dot_words[:, 1] + dot_words[:, 2]) * _U(0x0101010101010101)) >> _U(56)
    words += dot_words << _U(1)  # "." + 2 = "0"
    one_dot = dot_count == 1
    # the dot's column: 8 * word + byte, the byte from the power of two 2**(8 * byte) the dot's word is
    dot_word = (dot_words[:, 1] != 0) + 2 * (dot_words[:, 2] != 0)
    with np.errstate(divide="ignore"):
        dot_byte = np.log2((dot_words[:, 0] | dot_words[:, 1] | dot_words[:, 2]).astype(np.float64)) / 8
    fraction_digits = np.where(one_dot, _WIDTH - 1 - 8 * dot_word - dot_byte, 0).astype(np.int64)
    # every byte of the word an ASCII digit (simdjson's is_made_of_eight_digits_fast)
    digits = ((words & _HIGH_NIBBLES) | (((words + _SIX) & _HIGH_NIBBLES) >> _SHIFT_4)) == _THREES
    plain = digits[:, 0] & digits[:, 1] & digits[:, 2] & (dot_count <= 1) & (before >= 0)
    plain &= lengths > signed.astype(np.int64) + one_dot  # not "", "-", "." or "-." alone (bool + bool is "or")
    # the eight digits of each word (the first in the lowest byte) as one integer (simdjson's parse_eight_digits)
    words = ((words & _U(0x0F0F0F0F0F0F0F0F)) * _U(2561)) >> _SHIFT_8
    words = ((words & _U(0x00FF00FF00FF00FF)) * _U(6553601)) >> _SHIFT_16
    words = ((words & _U(0x0000FFFF0000FFFF)) * _U(42949672960001)) >> _SHIFT_32
    top, middle, low = words[:, 0], words[:, 1], words[:, 2]
    plain &= top <= _LARGEST_TOP_GROUP
    spread = top * _1E16 + middle * _1E8 + low  # the digits with the dot read as a 0: int * 10**(f+1) + frac
    # int * 10**f + frac; a longer fraction has no integer part (it would not fit the 24 bytes with top <= 1843)
    split = np.minimum(fraction_digits, _LONGEST_SPLIT)
    scale = _POW10_U64[split]
    mantissa = np.where(one_dot & (fraction_digits <= _LONGEST_SPLIT),
                        spread // _POW10_U64[split + 1] * scale + spread % scale, spread)
    fast = plain & (mantissa <= _CLINGER_MANTISSA) & (fraction_digits <= _CLINGER_EXPONENT)
    out = np.where(fast, mantissa / _POW10_DOUBLE[fraction_digits], np.nan)  # fast nearly everywhere: no gathers
    read = fast
    if _EXTENDED:
        wide = np.flatnonzero(plain & ~fast & (fraction_digits <= _EXTENDED_EXPONENT))
        if len(wide):
            quotient = mantissa[wide].astype(np.longdouble) / _POW10_EXTENDED[fraction_digits[wide]]
            low_bits = quotient.view(np.uint64).reshape(len(quotient), -1)[:, 0] & _HALFWAY_BITS
            once = low_bits != _HALFWAY  # not a halfway point: rounding it to a double is the one rounding
            out[wide[once]] = quotient[once].astype(np.float64)
            read = read.copy()
            read[wide[once]] = True
    negative = read & (first == _MINUS)
    np.negative(out, out=out, where=negative)
    rest = np.flatnonzero(plain & ~read)  # plain, but not read above (halfway, or no x87 long double): float()
    if len(rest):
        out[rest] = [float(buffer[start:start + length].tobytes())
                     for start, length in zip(starts[rest].tolist(), lengths[rest].tolist())]
        read = read | plain
    return out, read
