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

In memory, per process, bounded per kind (:attr:`Throttle.size` buckets of each): when a kind
is full, the buckets whose wait has passed go first, and a bucket that still waits goes only
when every bucket of its kind waits (the oldest first). So throwaway buckets (a new wrong key,
an unknown user name, from rotating addresses) cannot push out the bucket that is slowing a
guesser. The audit trail keeps the record (:mod:`opendnc.server.access.refusals`).
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

from opendnc.server.core.errors import TooManyRequests

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
# Failures past the free ones that are still counted: 2**30 s is past any sensible longest
# wait, and a float power past 1023 overflows (a bucket's count would otherwise grow forever).
_MOST_EXTRA = 30


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
        secret: bytes | None = None,
    ) -> None:
        self.free = dict(free)
        self.longest = longest
        self.size = size
        self.clock = clock
        # per kind, oldest first: (failures, waits until)
        self._failures: dict[str, OrderedDict[Bucket, tuple[int, float]]] = {}
        # per kind: no bucket's wait passes before this (set when a full kind was all waiting;
        # until then only a bucket added since can have passed, so no sweep is needed)
        self._waiting_until: dict[str, float] = {}
        self._lock = threading.Lock()  # routes run in worker threads
        # Signs device cookies. The server passes the key its database keeps
        # (shared_secrets.py), so every server of a cluster and a restarted one know the
        # cookies it issued; without one (a test, a tool) it is this process's own.
        self._secret = secret if secret is not None else secrets.token_bytes(32)

    def wait(self, buckets: Iterable[Bucket]) -> float:
        """Seconds until every one of ``buckets`` allows a try (0.0: now)."""
        now = self.clock()
        with self._lock:
            waits = [self._of(b.kind).get(b, (0, 0.0))[1] - now for b in buckets]
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
                kind = self._of(bucket.kind)
                free = self.free.get(bucket.kind, 5)
                count, _ = kind.get(bucket, (0, 0.0))
                count = min(count + 1, free + _MOST_EXTRA)
                extra = count - free
                until = (
                    now + min(2.0 ** min(extra, _MOST_EXTRA), self.longest) if extra > 0 else 0.0
                )
                kind.pop(bucket, None)
                kind[bucket] = (count, until)
                self._trim(bucket, now)

    def _of(self, kind: str) -> OrderedDict[Bucket, tuple[int, float]]:
        return self._failures.setdefault(kind, OrderedDict())

    def _trim(self, added: Bucket, now: float) -> None:
        """Keep ``added``'s kind within :attr:`size`: first the buckets whose wait has passed,
        then (every one waiting) the oldest."""
        name = added.kind
        kind = self._of(name)
        until = kind[added][1]
        bound = self._waiting_until.get(name, 0.0)
        if len(kind) <= self.size or (now < bound and until > now):
            self._waiting_until[name] = min(bound, until)
        if len(kind) <= self.size:
            return
        if now < bound:
            if until <= now:
                # every other bucket still waits: the one just added is the only one passed
                del kind[added]
                return
            kind.popitem(last=False)  # every bucket waits: the oldest goes
            return
        # one sweep drops every passed bucket: its cost is shared by the many adds it makes
        # room for
        for bucket in [b for b, (_, ends) in kind.items() if ends <= now]:
            del kind[bucket]
        if len(kind) > self.size:
            self._waiting_until[name] = min(ends for _, ends in kind.values())
            kind.popitem(last=False)  # every bucket waits: the oldest goes

    def succeeded(self, buckets: Iterable[Bucket]) -> None:
        """Forget the failures of each of ``buckets``."""
        with self._lock:
            for bucket in buckets:
                self._of(bucket.kind).pop(bucket, None)

    def reset(self) -> None:
        """Forget every failure."""
        with self._lock:
            self._failures.clear()
            self._waiting_until.clear()

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
