"""The server's edge: error echoes that always encode, JSON that holds only finite numbers, and
the body limit each route gets (issue 20 items 2 and 10)."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.peers import require_module

require_module("fastapi")

from opendnc.server.http.edge import ECHO_LIMIT, printable, strict_json  # noqa: E402
from opendnc.server.http.limits import Limits  # noqa: E402

anything = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats()
    | st.binary(max_size=1000)
    | st.text(max_size=1000),
    lambda inner: (
        st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=5), inner, max_size=5)
    ),
    max_leaves=20,
)


@given(anything)
def test_any_echoed_input_encodes_as_strict_json_and_stays_short(value: object) -> None:
    text = json.dumps(printable(value), allow_nan=False)
    assert len(text) < 60 * (ECHO_LIMIT + 10) * 20


def test_printable_keeps_what_is_already_printable() -> None:
    assert printable({"a": [1, 2.5, None, True, "x"]}) == {"a": [1, 2.5, None, True, "x"]}
    assert printable(b"\xff\xfeok") == "\ufffd\ufffdok"
    assert printable(math.inf) == "inf"
    assert printable("a" * 60000) == "a" * ECHO_LIMIT + "..."


@pytest.mark.parametrize(
    "text", ["1e400", "-1e400", "NaN", "Infinity", "-Infinity", '{"v": [1e999]}']
)
def test_non_finite_numbers_are_a_decode_error(text: str) -> None:
    with pytest.raises(json.JSONDecodeError):
        strict_json(text)


@given(
    st.recursive(
        st.none()
        | st.booleans()
        | st.integers()
        | st.floats(allow_nan=False, allow_infinity=False)
        | st.text(),
        lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
        max_leaves=15,
    )
)
def test_finite_json_reads_as_the_standard_library_reads_it(value: object) -> None:
    text = json.dumps(value)
    assert strict_json(text) == json.loads(text)
    assert strict_json(text.encode()) == json.loads(text)


def test_uploads_take_a_program_and_everything_else_a_mebibyte() -> None:
    limits = Limits()
    assert limits.body_limit("PUT", "/api/programs/O1.nc") == limits.max_upload
    assert limits.body_limit("POST", "/library") == limits.max_upload
    assert limits.body_limit("POST", "/machines/m1/files/upload") == limits.max_upload
    for method, path in [("POST", "/api/jobs"), ("POST", "/api/keys"), ("POST", "/login")]:
        assert limits.body_limit(method, path) == 1 << 20
