"""The collector pause around large answers: off while any question builds one, back on when
the last is done (also after an error), left off where it was off before."""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator

import pytest

from opendnc.server.core.gc_pause import paused


@pytest.fixture(autouse=True)
def _collector_on() -> Iterator[None]:
    gc.enable()
    yield
    gc.enable()


def test_paused_for_the_block_and_back_after_an_error() -> None:
    with paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(ZeroDivisionError), paused():
        _ = 1 / 0
    assert gc.isenabled()


def test_overlapping_questions_resume_it_when_the_last_ends() -> None:
    first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
    seen: list[bool] = []

    def second() -> None:
        first_in.wait(5)
        with paused():
            second_in.set()
            first_out.wait(5)
            seen.append(gc.isenabled())  # the first one ended, this one still builds
        seen.append(gc.isenabled())

    worker = threading.Thread(target=second)
    worker.start()
    with paused():
        first_in.set()
        assert second_in.wait(5)
    first_out.set()
    worker.join(5)
    assert seen == [False, True]


def test_a_collector_switched_off_stays_off() -> None:
    gc.disable()
    with paused():
        pass
    assert not gc.isenabled()
