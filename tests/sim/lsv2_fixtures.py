"""Shared fixtures: the virtual TNC (engineer D's simulator) on 127.0.0.1, port 0."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from opendnc.sim.tnc import TncHandle, start_tnc


@pytest.fixture(scope="module")
def tnc640() -> Iterator[TncHandle]:
    """A TNC 640 programming station in a background thread."""
    with start_tnc("tnc640") as handle:
        yield handle


@pytest.fixture(scope="module")
def itnc530() -> Iterator[TncHandle]:
    """An iTNC 530 (old attribute scheme, data paths, scope, NC errors, tool info)."""
    with start_tnc("itnc530") as handle:
        yield handle
