"""The cable's fault model, without ptys: rates, reproducibility, chunking independence."""

from __future__ import annotations

import itertools
import math
import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.sim.cable import LineNoise


def hamming(a: bytes, b: bytes) -> int:
    return sum(bin(x ^ y).count("1") for x, y in zip(a, b, strict=True))


def within_sigmas(observed: int, trials: int, p: float, sigmas: float = 5.0) -> bool:
    mean = trials * p
    return abs(observed - mean) <= sigmas * math.sqrt(trials * p * (1 - p))


def test_clean_line_is_identity() -> None:
    data = os.urandom(5000)
    result = LineNoise(0.0, 0.0, seed=1).apply(data)
    assert result.data == data
    assert (result.corrupted, result.dropped, result.bit_flips) == (0, 0, 0)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("ber", [1e-3, 1e-4])
def test_bit_error_rate_matches_and_counters_are_exact(seed: int, ber: float) -> None:
    data = bytes(200_000)
    result = LineNoise(ber, 0.0, seed=seed).apply(data)
    assert len(result.data) == len(data)
    flips = hamming(data, result.data)
    assert flips == result.bit_flips
    assert sum(1 for byte in result.data if byte) == result.corrupted
    assert within_sigmas(flips, len(data) * 8, ber), flips


@pytest.mark.parametrize("seed", [4, 5])
def test_drop_rate_matches(seed: int) -> None:
    data = bytes(range(256)) * 400
    result = LineNoise(0.0, 1e-2, seed=seed).apply(data)
    assert len(result.data) == len(data) - result.dropped
    assert result.corrupted == 0
    assert within_sigmas(result.dropped, len(data), 1e-2), result.dropped


def test_dropped_bytes_are_the_missing_ones() -> None:
    data = bytes(range(256)) * 4  # distinct values within each period of 256
    result = LineNoise(0.0, 0.05, seed=9).apply(data)
    # what survives is a subsequence of the input, in order
    it = iter(data)
    assert all(byte in it for byte in result.data)
    assert result.dropped > 0


def test_same_seed_same_faults_other_seed_other_faults() -> None:
    data = os.urandom(50_000)
    first = LineNoise(1e-3, 1e-3, seed=42).apply(data)
    again = LineNoise(1e-3, 1e-3, seed=42).apply(data)
    other = LineNoise(1e-3, 1e-3, seed=43).apply(data)
    assert first == again
    assert first.data != other.data


def test_unseeded_lines_differ() -> None:
    data = bytes(50_000)
    assert LineNoise(1e-3, 0.0).apply(data).data != LineNoise(1e-3, 0.0).apply(data).data


def test_certain_faults() -> None:
    assert LineNoise(1.0, 0.0, seed=0).apply(b"\x00\x0f").data == b"\xff\xf0"
    assert LineNoise(0.0, 1.0, seed=0).apply(b"abc").data == b""


@pytest.mark.parametrize(("ber", "drop"), [(-0.1, 0.0), (0.0, 1.5), (math.nan, 0.0)])
def test_bad_rates_are_input_errors(ber: float, drop: float) -> None:
    with pytest.raises(InputError):
        LineNoise(ber, drop)


@settings(max_examples=60, deadline=None)
@given(
    data=st.binary(min_size=1, max_size=3000),
    cuts=st.lists(st.integers(0, 3000), max_size=12),
    seed=st.integers(0, 2**32),
)
def test_faults_do_not_depend_on_chunking(data: bytes, cuts: list[int], seed: int) -> None:
    """The pump reads whatever the pty holds: the same stream must meet the same faults."""
    whole = LineNoise(0.01, 0.01, seed=seed).apply(data)
    line = LineNoise(0.01, 0.01, seed=seed)
    bounds = sorted({0, len(data), *(c for c in cuts if c < len(data))})
    pieces = [line.apply(data[a:b]) for a, b in itertools.pairwise(bounds)]
    assert b"".join(p.data for p in pieces) == whole.data
    assert sum(p.corrupted for p in pieces) == whole.corrupted
    assert sum(p.dropped for p in pieces) == whole.dropped
    assert sum(p.bit_flips for p in pieces) == whole.bit_flips
