"""Property tests: the macro table answers every write with a stored value or a reason."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.haas import macros
from opendnc.sim.haas.machine import MachineState

numbers = st.one_of(st.integers(-10, 60000), st.sampled_from([3000, 3901, 3902, 5081, 1063]))
values = st.one_of(st.none(), st.floats(), st.integers(-(10**25), 10**25).map(float))


@given(numbers, values)
def test_check_write_stores_within_the_rules_or_says_why(number: int, value: float | None) -> None:
    try:
        stored = macros.check_write(number, value)
    except InputError as exc:
        message = str(exc)
    else:
        message = ""
    if message:
        assert message.startswith(f"#{number} "), message  # names the variable written
        return
    span = macros.lookup(number)
    assert span is not None
    assert span.access is macros.Access.READ_WRITE
    if stored is None:
        assert value is None
        return
    assert stored == value
    if span.integer:
        assert stored == int(stored)
    if span.minimum is not None:
        assert stored >= span.minimum
    if span.maximum is not None:
        assert stored <= span.maximum


@given(numbers, values)
def test_machine_state_reads_back_what_it_accepted(number: int, value: float | None) -> None:
    machine = MachineState()
    try:
        machine.set(number, value)
    except InputError:
        return
    assert machine.get(number) == value
