"""The throttle's rules without a server: waits that double, an address's far higher
allowance, and device cookies that only this process issued for that user
(docs/server.md#throttling)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.server.access.throttle import FREE, Bucket, Throttle
from opendnc.server.core.errors import TooManyRequests

USER = Bucket("user", "a")


def test_each_failure_past_the_free_ones_doubles_the_wait() -> None:
    now = [0.0]
    guard = Throttle(free={"user": 2}, clock=lambda: now[0])
    guard.failed([USER, USER])
    guard.check([USER])  # the free ones cost nothing
    waits = []
    for _ in range(4):
        guard.failed([USER])
        with pytest.raises(TooManyRequests) as refused:
            guard.check([USER, Bucket("address", "x")])
        waits.append(refused.value.retry_after)
    assert waits == [2, 4, 8, 16]
    now[0] += 16
    guard.check([USER])
    guard.succeeded([USER])
    guard.failed([USER])
    guard.check([USER])


def test_the_wait_stops_growing_at_the_longest() -> None:
    guard = Throttle(free={"user": 0}, longest=900.0, clock=lambda: 0.0)
    for _ in range(40):
        guard.failed([USER])
    assert guard.wait([USER]) == 900.0


def test_an_address_takes_twenty_times_a_name_s_failures() -> None:
    guard = Throttle(clock=lambda: 0.0)
    address, name = Bucket("address", "10.0.0.1"), Bucket("user", "ann")
    for _ in range(FREE["user"]):
        guard.failed([name, address])
    guard.check([address, name])
    guard.failed([name, address])
    assert guard.wait([name]) > 0
    assert guard.wait([address]) == 0.0
    guard.failed([address] * (FREE["address"] - FREE["user"] - 1))
    assert guard.wait([address]) == 0.0
    guard.failed([address])
    assert guard.wait([address]) > 0
    assert FREE["address"] >= 20 * FREE["user"]


def test_a_device_cookie_names_only_the_users_who_logged_in_with_it() -> None:
    guard = Throttle()
    cookie = guard.device_cookie(None, "Ann")
    device = guard.device_of(cookie, "ann")  # user names are compared without case
    assert device is not None
    assert guard.device_of(cookie, "bob") is None
    both = guard.device_cookie(cookie, "bob")
    assert guard.device_of(both, "bob") == device
    assert guard.device_of(both, "ann") == device  # one browser, a shared terminal
    # forged, cut, from another process (another secret), or nonsense: not a known device
    forged = f"{device}:{'0' * 32}"
    assert guard.device_of(forged, "ann") is None
    assert guard.device_of(cookie[:-1], "ann") is None
    assert Throttle().device_of(cookie, "ann") is None
    for junk in ["", ":", "x" * 5000, "a:b:c", "\x00:\x00"]:
        assert guard.device_of(junk, "ann") is None
        assert guard.device_of(guard.device_cookie(junk, "ann"), "ann") is not None


def test_a_device_cookie_remembers_the_newest_eight_users() -> None:
    guard = Throttle()
    cookie = None
    for n in range(10):
        cookie = guard.device_cookie(cookie, f"user{n}")
    assert cookie is not None
    assert len(cookie) < 400
    known = [n for n in range(10) if guard.device_of(cookie, f"user{n}") is not None]
    assert known == list(range(2, 10))


@settings(max_examples=200, deadline=None)
@given(cookie=st.text(max_size=2000), user=st.text(min_size=1, max_size=64))
def test_any_cookie_is_a_known_device_only_if_this_throttle_issued_it(
    cookie: str, user: str
) -> None:
    guard = _GUARD
    assert guard.device_of(cookie, user) is None  # a browser's own text is never trusted
    issued = guard.device_cookie(cookie, user)
    assert guard.device_of(issued, user) is not None
    assert len(issued) <= 8 * 33 + 23


_GUARD = Throttle()


def test_a_bucket_s_thousands_of_failures_keep_it_waiting_and_counted() -> None:
    # 2.0**1024 overflowed after the bucket was taken out: it was forgotten, the try's other
    # buckets went uncounted, and the request ended in an exception
    guard = Throttle(free={"user": 0, "address": 0}, longest=900.0, clock=lambda: 0.0)
    address = Bucket("address", "x")
    for _ in range(1100):
        guard.failed([USER, address])
    assert guard.wait([USER]) == 900.0
    assert guard.wait([address]) == 900.0


def test_throwaway_buckets_never_push_out_one_that_waits() -> None:
    now = [0.0]
    guard = Throttle(free={"user": 2, "key": 5}, size=50, clock=lambda: now[0])
    guard.failed([USER] * 5)  # the guessed name waits 8 s
    guard.failed([Bucket("user", f"old{i}") for i in range(10) for _ in range(3)])  # 2 s
    now[0] += 3
    # wrong keys and unknown names, each new: far more than the bound holds
    for i in range(500):
        guard.failed([Bucket("key", f"junk{i}"), Bucket("user", f"nobody{i}")])
    assert guard.wait([USER]) == 5.0
    assert guard.wait([Bucket("user", "old1")]) == 0.0
    assert all(len(kind) <= 50 for kind in guard._failures.values())
    # every bucket of the kind waits: only then does the oldest go
    full = Throttle(free={"user": 0}, size=50, clock=lambda: now[0])
    full.failed([USER])
    full.failed([Bucket("user", f"late{i}") for i in range(50)])
    assert full.wait([USER]) == 0.0
    assert full.wait([Bucket("user", "late0")]) == 2.0
