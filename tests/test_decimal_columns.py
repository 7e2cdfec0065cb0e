"""decimal_columns.decimals_at: every number bit for bit float()'s, whichever path it takes."""

from __future__ import annotations

from decimal import Decimal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tavf_mapkit.opendrive.decimal_columns import decimals_at


def read(texts: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """decimals_at over the texts written as attribute values, as the planView scan finds them."""
    buffer = np.frombuffer(b'<g s="' + b'" x="'.join(texts) + b'"/>', dtype=np.uint8)
    quotes = np.flatnonzero(buffer == ord('"'))
    return decimals_at(buffer, quotes[1::2], quotes[1::2] - quotes[0::2] - 1)


def assert_as_float(texts: list[bytes]) -> None:
    """A text in the plain form (sign, digits, one dot) of at most 19 bytes after the sign is read, a longer one
    may be; all read bit for bit as float() reads them (-0.0 and 0.0 differ); others are not read."""
    expected = np.array([float(text) for text in texts])
    got, was_read = read(texts)
    plain = np.array([b"e" not in text.lower() and len(text.lstrip(b"+-")) <= 24 for text in texts])
    short = plain & np.array([len(text.lstrip(b"+-")) <= 19 for text in texts])
    assert not np.any(was_read & ~plain) and not np.any(short & ~was_read), [
        text for text, ok, want in zip(texts, was_read, short) if ok != want][:5]
    differ = np.flatnonzero((got.view(np.int64) != expected.view(np.int64)) & was_read)
    assert not len(differ), [(texts[i], got[i], expected[i]) for i in differ[:5]]


def test_netconvert_numbers_and_their_round_trip_forms():
    rng = np.random.default_rng(15)
    values = np.concatenate([rng.normal(0, 3000, 20000), rng.normal(0, 1, 20000), rng.normal(0, 0.003, 20000)])
    texts = [repr(float(v)).encode() for v in values]
    for digits in (0, 3, 8, 15, 16, 17, 19, 21):
        texts += [b"%.*f" % (digits, v) for v in values[::30]]
        texts += [b"%.*g" % (digits, v) for v in values[::30]]
    assert_as_float(texts)


def test_numbers_halfway_between_two_doubles_are_rounded_once():
    # the extended-precision quotient of these is exactly halfway: they must go to float(), which rounds to even
    rng = np.random.default_rng(7)
    texts = [str(2**53 + 2 * k + 1).encode() for k in range(200)]
    for _ in range(2000):
        mantissa, exponent = int(rng.integers(2**52, 2**53)), -int(rng.integers(1, 12))
        text = format(Decimal(2 * mantissa + 1) * Decimal(2) ** (exponent - 1), "f")
        if len(text) <= 23:
            texts += [text.encode(), b"-" + text.encode()]
    assert_as_float(texts)


@pytest.mark.parametrize("text", [b"0", b"-0", b"-0.0", b"+5", b"5.", b".5", b"-.5", b"007.25", b"1" * 24,
                                  b"-" + b"1" * 24, b"0.00000000000000000001", b"-0.0000000000000000000001",
                                  b"18446744073709551615", b"1843999999999999.99999", b"000000000000000000000001.5"])
def test_edge_forms_as_float(text):
    assert_as_float([text, b"1.5"])


@pytest.mark.parametrize("text", [b"", b"-", b"+", b".", b"-.", b"1.2.3", b"--1", b"1-2", b"1e5", b"1e5e5", b"e5",
                                  b"nan", b"inf", b"1_0", b" 1", b"9" * 30, b"18446744073709551616"])
def test_other_forms_are_left_to_the_caller(text):
    values, was_read = read([b"2.5", text, b"-3"])
    assert was_read.tolist() == [True, False, True]
    assert values[0] == 2.5 and values[2] == -3.0 and np.isnan(values[1])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.from_regex(rb"\A[-+]?[0-9]{0,12}\.?[0-9]{0,14}\Z").filter(
    lambda text: any(c in b"0123456789" for c in text)), min_size=1, max_size=40))
def test_any_plain_decimal_as_float(texts):
    assert_as_float(texts)
