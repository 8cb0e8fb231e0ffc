"""Sessions for people in a browser: a short-lived API key in an HttpOnly cookie.

Logging in creates a key for the user, labelled as a web session, and puts it in a cookie
the page's scripts cannot read (``HttpOnly``) and the browser never sends from another site
(``SameSite=Strict``). Such a key is valid only as this cookie, never as an API key
(:func:`opendnc.server.auth.check_key`), so it cannot outlive the session. Logging out revokes
it; a session older than :data:`SESSION_HOURS` is refused (and revoked). Keeping sessions as
keys means one look-up, one revocation path and one audit trail, with no new table. A login
is audited as ``login`` (refused ones too, in a transaction of their own) and slowed after
repeated failures per user and per address (:class:`opendnc.server.auth.LoginGuard`).

Writes from a page also carry a CSRF token: a hash of the session key that only a page served
to that session knows. ``SameSite=Strict`` already keeps other sites' forms from carrying the
cookie; the token keeps that true in browsers or proxies that ignore the attribute.
"""

from __future__ import annotations

import hashlib
import hmac
from datetime import timedelta

from fastapi import Request, Response
from sqlalchemy import select
from sqlalchemy.orm import Session, joinedload, sessionmaker

from opendnc.server import audit, auth
from opendnc.server.auth import SESSION_LABEL
from opendnc.server.errors import Forbidden, Unauthorized
from opendnc.server.key_use import KeyUse
from opendnc.server.store.models import ApiKey, utcnow

__all__ = [
    "COOKIE",
    "CSRF_HEADER",
    "SESSION_HOURS",
    "check_csrf",
    "csrf_token",
    "log_in",
    "log_out",
    "principal",
]

COOKIE = "opendnc_session"
CSRF_HEADER = "X-CSRF-Token"
CSRF_FIELD = "csrf"
SESSION_HOURS = 12


def csrf_token(key: str) -> str:
    """The CSRF token of the session ``key`` (derived, so nothing more is stored)."""
    return hashlib.sha256(b"opendnc-csrf\x00" + key.encode()).hexdigest()


def log_in(
    sessions: sessionmaker[Session],
    guard: auth.LoginGuard,
    response: Response,
    name: str,
    password: str,
    *,
    secure: bool,
    address: str,
) -> auth.Principal:
    """Check the password and set the session cookie on ``response`` (audited as ``login``;
    :class:`~opendnc.server.errors.TooManyRequests` after repeated failures)."""
    who_keys = (f"user:{name.lower()}", f"address:{address}")
    guard.check(*who_keys)
    try:
        with sessions.begin() as session:
            who = auth.check_password(session, name, password)
    except Unauthorized:
        guard.failed(*who_keys)
        with sessions.begin() as session:  # the refusal is recorded although nothing else is
            audit.record(session, name[:64], "login", result="refused", via="web", address=address)
        raise
    guard.succeeded(*who_keys)
    with sessions.begin() as session:
        _, key = auth.create_key(
            session,
            who.name,
            who.role,
            label=SESSION_LABEL,
            actor=who.name,
            action="login",
            via="web",
            address=address,
        )
    response.set_cookie(
        COOKIE,
        key,
        max_age=SESSION_HOURS * 3600,
        httponly=True,
        samesite="strict",
        secure=secure,
        path="/",
    )
    return who


def log_out(
    sessions: sessionmaker[Session], keys: auth.KeyCache, request: Request, response: Response
) -> None:
    """Revoke the session's key (forgetting it in ``keys``) and clear the cookie."""
    key = request.cookies.get(COOKIE)
    response.delete_cookie(COOKIE, path="/")
    if not key:
        return
    with sessions.begin() as session:
        row = session.scalar(
            select(ApiKey)
            .where(ApiKey.key_hash == auth.key_hash(key))
            .options(joinedload(ApiKey.user))
        )
        if row is None or row.label != SESSION_LABEL:
            return
        auth.revoke_key(session, row.id, actor=row.user.name)
        key_id = row.id
    keys.forget(key_id)


def principal(
    reads: sessionmaker[Session],
    sessions: sessionmaker[Session],
    uses: KeyUse,
    keys: auth.KeyCache,
    request: Request,
) -> tuple[auth.Principal, str]:
    """Who the session cookie stands for, and its key; :class:`Unauthorized` if none.

    Reads only (the use is noted in ``uses``; a key checked a moment ago is taken from
    ``keys``), except for the revocation of an expired session."""
    key = request.cookies.get(COOKIE)
    if not key:
        raise Unauthorized("log in first")
    check = auth.authenticate(reads, key, uses, keys, web=True)
    if utcnow() - check.created > timedelta(hours=SESSION_HOURS):
        with sessions.begin() as session:
            assert check.who.key_id is not None
            auth.revoke_key(session, check.who.key_id, actor="server")
        keys.forget(check.who.key_id)
        raise Unauthorized("the session has expired; log in again")
    return check.who, key


def check_csrf(request: Request, key: str, form_token: str | None = None) -> None:
    """Refuse a write whose CSRF token (header or form field) is not the session's."""
    sent = request.headers.get(CSRF_HEADER) or form_token or ""
    if not hmac.compare_digest(sent.encode(), csrf_token(key).encode()):
        raise Forbidden("the request did not come from a page of this server (CSRF token)")
    origin = request.headers.get("origin")
    if origin and origin.rstrip("/") != str(request.base_url).rstrip("/"):
        raise Forbidden(f"a write from {origin} is refused")
