"""Slowing down guessing without locking out the innocent (docs/server.md#throttling).

Failed credentials are counted in *buckets*: a user name, an API key's prefix, a browser
that has logged in as a user before (its *device*), and an address. The first few failures
of a bucket cost nothing; each one after makes the bucket wait twice as long (2 s, 4 s, ...
at most :attr:`Throttle.longest`). What a refusal may cost the innocent decides which
buckets a try is measured against:

* An API key is always checked first: a valid key is never refused, whatever others sent.
  Only a wrong key is answered 429 instead of 401 while its prefix or its address waits.
* A password is measured against its user name and its address, unless the browser carries
  a device cookie for that user name (:meth:`Throttle.device_cookie`), which it got by logging
  in as that user before: then only the device's own failures count. Someone guessing a
  user's password slows every new browser for that name, never the user's own.
* An address is a bucket only for guesses, and with a far higher allowance
  (:data:`FREE`): a proxy or the server's own host carries many people's logins.

In memory, per process, bounded (the oldest buckets go first). The audit trail keeps the
record (:mod:`opendnc.server.refusals`).
"""

from __future__ import annotations

import hashlib
import hmac
import math
import re
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from opendnc.server.errors import TooManyRequests

__all__ = ["DEVICE_COOKIE", "DEVICE_DAYS", "FREE", "Bucket", "Throttle"]

# Failures each kind of bucket may have before it waits. An address carries every person
# behind it (a reverse proxy, the server's own host), so it gets twenty times a name's.
FREE: Mapping[str, int] = {
    "user": 5,
    "device": 5,
    "key": 5,
    "address": 100,
    "key-address": 100,
}
DEVICE_COOKIE = "opendnc_device"
DEVICE_DAYS = 90
_DEVICE_USERS = 8  # user names one browser is known for (a shared terminal in the shop)
# what this module writes: token_urlsafe(16) and a hex HMAC cut to 32 digits (a cookie that
# holds anything else was not written here, and is not echoed back)
_DEVICE = re.compile(r"[A-Za-z0-9_-]{22}")
_MARK = re.compile(r"[0-9a-f]{32}")


@dataclass(frozen=True)
class Bucket:
    """What failures are counted against: a ``kind`` of :data:`FREE` and its value."""

    kind: str
    value: str

    def __str__(self) -> str:
        return f"{self.kind}:{self.value}"


class Throttle:
    """Failure counts per bucket, the waits they cause, and the device cookies (see module)."""

    def __init__(
        self,
        *,
        free: Mapping[str, int] = FREE,
        longest: float = 900.0,
        size: int = 10_000,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.free = dict(free)
        self.longest = longest
        self.size = size
        self.clock = clock
        self._failures: OrderedDict[Bucket, tuple[int, float]] = OrderedDict()
        self._lock = threading.Lock()  # routes run in worker threads
        # Signs device cookies. Per process: after a restart (or on another server sharing
        # the database) a browser is new again, which costs it nothing unless its user name
        # is being guessed at that moment.
        self._secret = secrets.token_bytes(32)

    def wait(self, buckets: Iterable[Bucket]) -> float:
        """Seconds until every one of ``buckets`` allows a try (0.0: now)."""
        now = self.clock()
        with self._lock:
            waits = [self._failures.get(b, (0, 0.0))[1] - now for b in buckets]
        return max([0.0, *waits])

    def check(self, buckets: Iterable[Bucket]) -> None:
        """Refuse with :class:`TooManyRequests` while any of ``buckets`` must wait."""
        wait = self.wait(buckets)
        if wait > 0:
            seconds = math.ceil(wait)
            raise TooManyRequests(
                f"too many failed attempts; try again in {seconds} s", retry_after=seconds
            )

    def failed(self, buckets: Iterable[Bucket]) -> None:
        """Count a failure for each of ``buckets``."""
        now = self.clock()
        with self._lock:
            for bucket in buckets:
                count, _ = self._failures.pop(bucket, (0, 0.0))
                count += 1
                extra = count - self.free.get(bucket.kind, 5)
                until = now + min(2.0**extra, self.longest) if extra > 0 else 0.0
                self._failures[bucket] = (count, until)
            while len(self._failures) > self.size:
                self._failures.popitem(last=False)

    def succeeded(self, buckets: Iterable[Bucket]) -> None:
        """Forget the failures of each of ``buckets``."""
        with self._lock:
            for bucket in buckets:
                self._failures.pop(bucket, None)

    def reset(self) -> None:
        """Forget every failure."""
        with self._lock:
            self._failures.clear()

    # -- device cookies ---------------------------------------------------------------------

    def _mark(self, device: str, user: str) -> str:
        message = f"{device}\x00{user.lower()}".encode("utf-8", "surrogatepass")
        return hmac.new(self._secret, message, hashlib.sha256).hexdigest()[:32]

    def device_of(self, cookie: str | None, user: str) -> str | None:
        """The device id in ``cookie`` if it was issued here to a browser that logged in as
        ``user``; None otherwise (no cookie, another user's, forged, another process's)."""
        if not cookie or len(cookie) > 1024:
            return None
        device, _, marks = cookie.partition(":")
        if not device or not marks:
            return None
        mark = self._mark(device, user)
        # compare_digest takes ASCII text only: a mark with anything else is not ours
        known = any(m.isascii() and hmac.compare_digest(mark, m) for m in marks.split(","))
        return device if known else None

    def device_cookie(self, cookie: str | None, user: str) -> str:
        """The device cookie to set after ``user`` logged in: ``cookie``'s device (a new one
        if it has none valid), now known for ``user`` as well (the newest few users)."""
        device, marks = "", [""]
        if cookie and len(cookie) <= 1024:
            device, _, joined = cookie.partition(":")
            marks = joined.split(",")
        if not _DEVICE.fullmatch(device):
            device, marks = secrets.token_urlsafe(16), []
        mark = self._mark(device, user)
        # keep only marks that could be ours (a forged list stays short)
        kept = [m for m in marks if _MARK.fullmatch(m) and m != mark]
        kept = kept[-(_DEVICE_USERS - 1) :]
        return f"{device}:{','.join([*kept, mark])}"
