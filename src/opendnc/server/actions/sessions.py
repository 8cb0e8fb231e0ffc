"""Session actions: a person logs in with a password and gets a short-lived key (a web
session), the page asks who a session stands for, and logging out revokes it.

The cookies that carry the key and the CSRF tokens are the pages'
(:mod:`opendnc.server.web.session`); the password check, the throttle, the key and its audit
trail are here. A login is audited as
``login`` (refused ones summed per minute, :mod:`opendnc.server.access.refusals`) and slowed after
repeated failures (:class:`opendnc.server.access.throttle.Throttle`), never for a browser that
logged in as that user before, because of someone else's failures.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

from opendnc.server.access import auth
from opendnc.server.access.key_use import KeyUse
from opendnc.server.access.refusals import Refusals
from opendnc.server.access.throttle import Bucket
from opendnc.server.actions.base import Caller, Services
from opendnc.server.core.errors import TooManyRequests, Unauthorized
from opendnc.server.store.models import utcnow

__all__ = ["SESSION_HOURS", "LoggedIn", "log_in", "log_out", "session_of"]

SESSION_HOURS = 12
"""A session older than this is refused (and revoked)."""


@dataclass(frozen=True)
class LoggedIn:
    """A login that succeeded: who, the session's key, and the browser's device cookie (which
    names the users who logged in from it, docs/server.md#throttling)."""

    who: Caller
    key: str
    device: str


def log_in(
    svc: Services,
    refusals: Refusals,
    name: str,
    password: str,
    *,
    address: str,
    device: str | None = None,
) -> LoggedIn:
    """Check the password and create the session's key (audited as ``login``;
    :class:`~opendnc.server.core.errors.TooManyRequests` after repeated failures).

    ``device`` is the browser's device cookie: one that names this user limits the throttle
    to the browser's own failures (docs/server.md#throttling)."""
    guard = svc.guard
    known = guard.device_of(device, name)
    buckets = (
        [Bucket("device", f"{known}:{name.lower()}")]
        if known is not None
        else [Bucket("user", name.lower()), Bucket("address", address)]
    )
    try:
        guard.check(buckets)
    except TooManyRequests as exc:
        refusals.note(
            actor=name, via="web", address=address, name=name, error=str(exc), throttled=True
        )
        raise
    try:
        who = svc.write(lambda s: auth.check_password(s, name, password))
    except Unauthorized as exc:
        guard.failed(buckets)
        refusals.note(actor=name, via="web", address=address, name=name, error=str(exc))
        raise
    # The user's bucket stays as it is after a login from a known browser: the failures in
    # it are someone else's, and forgetting them would give a guesser a fresh allowance.
    guard.succeeded(buckets[:1])
    _, key = svc.write(
        lambda s: auth.create_key(
            s,
            who.name,
            who.role,
            label=auth.SESSION_LABEL,
            actor=who.name,
            action="login",
            via="web",
            address=address,
        )
    )
    return LoggedIn(who, key, guard.device_cookie(device, who.name))


def log_out(svc: Services, key: str) -> None:
    """Revoke the session ``key`` (and forget it in the key cache); a key that is no
    session's is left alone."""
    key_id = svc.write(lambda s: auth.revoke_session(s, key))
    if key_id is not None:
        svc.keys.forget(key_id)


def session_of(svc: Services, uses: KeyUse, key: str) -> Caller:
    """Who the session ``key`` stands for; :class:`Unauthorized` if none.

    Reads only (the use is noted in ``uses``; a key checked a moment ago is taken from the
    key cache), except for the revocation of an expired session."""
    check = auth.authenticate(svc.reads, key, uses, svc.keys, web=True)
    if utcnow() - check.created > timedelta(hours=SESSION_HOURS):
        key_id = check.who.key_id
        assert key_id is not None
        svc.write(lambda s: auth.revoke_key(s, key_id, actor="server"))
        svc.keys.forget(key_id)
        raise Unauthorized("the session has expired; log in again")
    return check.who
