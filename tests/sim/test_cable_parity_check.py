"""The virtual cable's optional parity check (a character failing it arrives as NUL)."""

from __future__ import annotations

from opendnc.sim.cable.noise import LineNoise


def test_odd_flips_arrive_as_nul_with_parity_check_and_flipped_without() -> None:
    data = bytes(range(1, 256)) * 40
    plain = LineNoise(ber=0.01, seed=3).apply(data)
    checked = LineNoise(ber=0.01, seed=3, parity_check=True).apply(data)
    assert plain.corrupted == checked.corrupted > 0
    for sent, a, b in zip(data, plain.data, checked.data, strict=True):
        flips = bin(sent ^ a).count("1")
        if flips == 0:
            assert b == sent
        elif flips % 2:
            assert b == 0  # parity error: the UART hands over NUL
        else:
            assert b == a  # two flips in one character pass the parity check
