"""Shared fixtures: the virtual TNC on 127.0.0.1, port 0, and a way to pin its machine state."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from opendnc.lsv2.constants import ExecutionMode, ProgramState
from opendnc.sim.tnc import Control, TncHandle, start_tnc


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


@contextmanager
def pinned_state(tnc: TncHandle, program: ProgramState, mode: ExecutionMode) -> Iterator[None]:
    """Put the simulated machine in ``program``/``mode`` (restored afterwards).

    A client read can then be compared with a value the test chose, instead of with "any
    member of the enum", which cannot fail.
    """

    def get(control: Control) -> tuple[ProgramState, ExecutionMode]:
        return control.machine.program_state, control.machine.exec_mode

    def put(state: tuple[ProgramState, ExecutionMode]) -> Callable[[Control], None]:
        def apply(control: Control) -> None:
            control.machine.program_state, control.machine.exec_mode = state

        return apply

    before = tnc.call(get)
    tnc.call(put((program, mode)))
    try:
        yield
    finally:
        tnc.call(put(before))
