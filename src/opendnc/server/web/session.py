"""Sessions for people in a browser: a short-lived API key in an HttpOnly cookie.

Logging in creates a key for the user, labelled as a web session, and puts it in a cookie
the page's scripts cannot read (``HttpOnly``) and the browser never sends from another site
(``SameSite=Strict``). Such a key is valid only as this cookie, never as an API key
(:func:`opendnc.server.access.auth.check_key`), so it cannot outlive the session. Logging out
revokes it; a session older than :data:`SESSION_HOURS` is refused (and revoked). Keeping sessions as
keys means one look-up, one revocation path and one audit trail, with no new table. The
password check, the throttle and the key are the session actions'
(:mod:`opendnc.server.actions.sessions`); this module keeps the cookies and the CSRF tokens.

Writes from a page also carry a CSRF token: a hash of the session key that only a page served
to that session knows. ``SameSite=Strict`` already keeps other sites' forms from carrying the
cookie; the token keeps that true in browsers or proxies that ignore the attribute. The login
form carries one too, from a cookie of its own (:func:`login_token`).
"""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets

from fastapi import Request, Response

from opendnc.server.access import auth
from opendnc.server.access.key_use import KeyUse
from opendnc.server.access.refusals import Refusals
from opendnc.server.access.throttle import DEVICE_COOKIE, DEVICE_DAYS
from opendnc.server.actions import Services, sessions
from opendnc.server.actions.sessions import SESSION_HOURS
from opendnc.server.core.errors import Forbidden, Unauthorized

__all__ = [
    "COOKIE",
    "CSRF_HEADER",
    "LOGIN_COOKIE",
    "SESSION_HOURS",
    "check_csrf",
    "check_login_csrf",
    "csrf_token",
    "log_in",
    "log_out",
    "login_token",
    "principal",
    "set_login_cookie",
]

COOKIE = "opendnc_session"
CSRF_HEADER = "X-CSRF-Token"
CSRF_FIELD = "csrf"
LOGIN_COOKIE = "opendnc_login"  # the login form's CSRF token (see login_token)
LOGIN_TOKEN_HOURS = 12
_LOGIN_TOKEN = re.compile(r"[A-Za-z0-9_-]{43}")  # secrets.token_urlsafe(32)


def csrf_token(key: str) -> str:
    """The CSRF token of the session ``key`` (derived, so nothing more is stored)."""
    return hashlib.sha256(b"opendnc-csrf\x00" + key.encode()).hexdigest()


def log_in(
    svc: Services,
    refusals: Refusals,
    response: Response,
    name: str,
    password: str,
    *,
    secure: bool,
    address: str,
    device: str | None = None,
) -> auth.Principal:
    """Log in (:func:`opendnc.server.actions.sessions.log_in`) and set the session cookie and
    the browser's device cookie on ``response``."""
    done = sessions.log_in(svc, refusals, name, password, address=address, device=device)
    response.set_cookie(
        COOKIE,
        done.key,
        max_age=SESSION_HOURS * 3600,
        httponly=True,
        samesite="strict",
        secure=secure,
        path="/",
    )
    response.set_cookie(
        DEVICE_COOKIE,
        done.device,
        max_age=DEVICE_DAYS * 86400,
        httponly=True,
        samesite="strict",
        secure=secure,
        path="/login",
    )
    return done.who


def login_token(request: Request) -> tuple[str, bool]:
    """The login form's CSRF token: the browser's login cookie, or a new one (True: set it).

    Before a login there is no session to derive a token from, so the token is a random value
    in a cookie of its own that the form repeats (a cookie another site can neither read nor
    send, ``SameSite=Strict``): a cross-site ``POST /login`` has the field but not the cookie
    (login CSRF: logging a victim in as the attacker)."""
    sent = request.cookies.get(LOGIN_COOKIE, "")
    if _LOGIN_TOKEN.fullmatch(sent):  # only what login_token writes is repeated in the form
        return sent, False
    return secrets.token_urlsafe(32), True


def set_login_cookie(response: Response, token: str, *, secure: bool) -> None:
    """Give the browser the login form's token (see :func:`login_token`)."""
    response.set_cookie(
        LOGIN_COOKIE,
        token,
        max_age=LOGIN_TOKEN_HOURS * 3600,
        httponly=True,
        samesite="strict",
        secure=secure,
        path="/login",
    )


def check_login_csrf(request: Request, form_token: str | None) -> None:
    """Refuse a login whose form token is not the browser's login cookie, or that comes from
    another site's page (:class:`Forbidden`)."""
    cookie = request.cookies.get(LOGIN_COOKIE, "")
    sent = form_token or ""
    same = _LOGIN_TOKEN.fullmatch(cookie) and hmac.compare_digest(
        sent.encode("utf-8", "surrogatepass"), cookie.encode()
    )
    if not same:
        raise Forbidden("the login did not come from this server's login page; log in again")
    origin = request.headers.get("origin")
    if origin and origin.rstrip("/") != str(request.base_url).rstrip("/"):
        raise Forbidden(f"a login from {origin} is refused")


def log_out(svc: Services, request: Request, response: Response) -> None:
    """Revoke the session's key and clear the cookie."""
    key = request.cookies.get(COOKIE)
    response.delete_cookie(COOKIE, path="/")
    if key:
        sessions.log_out(svc, key)


def principal(svc: Services, uses: KeyUse, request: Request) -> tuple[auth.Principal, str]:
    """Who the session cookie stands for, and its key; :class:`Unauthorized` if none."""
    key = request.cookies.get(COOKIE)
    if not key:
        raise Unauthorized("log in first")
    return sessions.session_of(svc, uses, key), key


def check_csrf(request: Request, key: str, form_token: str | None = None) -> None:
    """Refuse a write whose CSRF token (header or form field) is not the session's."""
    sent = request.headers.get(CSRF_HEADER) or form_token or ""
    if not hmac.compare_digest(sent.encode(), csrf_token(key).encode()):
        raise Forbidden("the request did not come from a page of this server (CSRF token)")
    origin = request.headers.get("origin")
    if origin and origin.rstrip("/") != str(request.base_url).rstrip("/"):
        raise Forbidden(f"a write from {origin} is refused")
