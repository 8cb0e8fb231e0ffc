"""Sessions for people in a browser: a short-lived API key in an HttpOnly cookie.

Logging in creates an ordinary API key for the user, labelled as a web session, and puts it
in a cookie the page's scripts cannot read (``HttpOnly``) and the browser never sends from
another site (``SameSite=Strict``). Logging out revokes it; a session older than
:data:`SESSION_HOURS` is refused (and revoked). Keeping sessions as keys means one look-up,
one revocation path and one audit trail for people and programs alike, with no new table.

Writes from a page also carry a CSRF token: a hash of the session key that only a page served
to that session knows. ``SameSite=Strict`` already keeps other sites' forms from carrying the
cookie; the token keeps that true in browsers or proxies that ignore the attribute.
"""

from __future__ import annotations

import hashlib
import hmac
from datetime import UTC, timedelta

from fastapi import Request, Response
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server import auth
from opendnc.server.errors import Forbidden, Unauthorized
from opendnc.server.store.models import ApiKey, Role, utcnow

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
SESSION_LABEL = "web session"


def csrf_token(key: str) -> str:
    """The CSRF token of the session ``key`` (derived, so nothing more is stored)."""
    return hashlib.sha256(b"opendnc-csrf\x00" + key.encode()).hexdigest()


def log_in(
    sessions: sessionmaker[Session], response: Response, name: str, password: str, secure: bool
) -> auth.Principal:
    """Check the password and set the session cookie on ``response``."""
    with sessions.begin() as session:
        who = auth.check_password(session, name, password)
    # The login is committed (and audited) even when the key cannot be made.
    with sessions.begin() as session:
        _, key = auth.create_key(session, who.name, who.role, label=SESSION_LABEL, actor=who.name)
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


def log_out(sessions: sessionmaker[Session], request: Request, response: Response) -> None:
    """Revoke the session's key and clear the cookie."""
    key = request.cookies.get(COOKIE)
    response.delete_cookie(COOKIE, path="/")
    if not key:
        return
    with sessions.begin() as session:
        row = session.scalar(select(ApiKey).where(ApiKey.key_hash == auth.key_hash(key)))
        if row is not None and row.label == SESSION_LABEL:
            auth.revoke_key(session, row.id, actor=row.user.name)


def principal(sessions: sessionmaker[Session], request: Request) -> tuple[auth.Principal, str]:
    """Who the session cookie stands for, and its key; :class:`Unauthorized` if none."""
    key = request.cookies.get(COOKIE)
    if not key:
        raise Unauthorized("log in first")
    with sessions.begin() as session:
        who = auth.authenticate_key(session, key)
        row = session.get(ApiKey, who.key_id)
        if row is None or row.label != SESSION_LABEL:
            # An API key pasted into a cookie is not a session: people log in.
            raise Unauthorized("not a web session")
        created = row.created
        if created.tzinfo is None:  # SQLite hands the stored UTC time back without its zone
            created = created.replace(tzinfo=UTC)
        expired = utcnow() - created > timedelta(hours=SESSION_HOURS)
        if expired:
            auth.revoke_key(session, row.id, actor="server")  # committed with the block
    if expired:
        raise Unauthorized("the session has expired; log in again")
    return who, key


def check_csrf(request: Request, key: str, form_token: str | None = None) -> None:
    """Refuse a write whose CSRF token (header or form field) is not the session's."""
    sent = request.headers.get(CSRF_HEADER) or form_token or ""
    if not hmac.compare_digest(sent.encode(), csrf_token(key).encode()):
        raise Forbidden("the request did not come from a page of this server (CSRF token)")
    origin = request.headers.get("origin")
    if origin and origin.rstrip("/") != str(request.base_url).rstrip("/"):
        raise Forbidden(f"a write from {origin} is refused")


def need(who: auth.Principal, role: Role) -> None:
    """Refuse ``who`` unless it has at least ``role`` (the same rule as the API)."""
    if not who.can(role):
        raise Forbidden(f"{who.name} is {who.role.name.lower()}; this needs {role.name.lower()}")
