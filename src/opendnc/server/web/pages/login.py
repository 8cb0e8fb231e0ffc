"""The login page, logging in and out (the session itself: :mod:`opendnc.server.web.session`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Form, Request
from fastapi.responses import RedirectResponse, Response

from opendnc.errors import InputError
from opendnc.server.access.throttle import DEVICE_COOKIE
from opendnc.server.core.errors import Forbidden, TooManyRequests, Unauthorized
from opendnc.server.web import session as web_session
from opendnc.server.web.pages.base import Shop, Writing, html

__all__ = ["router"]

router = APIRouter(include_in_schema=False)


@router.get("/login")
def login_form(request: Request, next: str = "/") -> Response:
    """The login page (with the form's CSRF token, web_session.login_token)."""
    return _login_page(request, next, "", "", 200)


def _login_page(request: Request, next: str, error: str, username: str, status: int) -> Response:
    token, new = web_session.login_token(request)
    page = html(
        "login.html",
        None,
        request,
        next=_safe_next(next),
        error=error,
        username=username,
        login_csrf=token,
    )
    page.status_code = status
    if new:
        web_session.set_login_cookie(page, token, secure=request.url.scheme == "https")
    return page


def _safe_next(target: str) -> str:
    # Only paths on this server: never an open redirect to another site.
    return target if target.startswith("/") and not target.startswith("//") else "/"


@router.post("/login", response_model=None)
def login(
    request: Request,
    shop: Shop,
    username: Annotated[str, Form()],
    password: Annotated[str, Form()],
    next: Annotated[str, Form()] = "/",
    csrf: Annotated[str, Form(max_length=100)] = "",
) -> Response:
    """Check the form's token and the password, start a session, go where the user was
    heading (docs/server.md#throttling)."""
    response = RedirectResponse(_safe_next(next), status_code=303)
    address = request.client.host if request.client else "?"
    try:
        web_session.check_login_csrf(request, csrf)
        web_session.log_in(
            shop.svc,
            shop.refusals,
            response,
            username,
            password,
            secure=request.url.scheme == "https",
            address=address,
            device=request.cookies.get(DEVICE_COOKIE),
        )
    except Forbidden as exc:
        shop.refusals.note(
            actor=username, via="web", address=address, name=username, error=str(exc)
        )
        return _login_page(request, next, str(exc), username, 403)
    except TooManyRequests as exc:
        page = _login_page(request, next, str(exc), username, 429)
        page.headers["Retry-After"] = str(exc.retry_after)
        return page
    except (Unauthorized, InputError) as exc:
        return _login_page(request, next, str(exc), username, 401)
    return response


@router.post("/logout")
def logout(request: Request, page: Writing) -> RedirectResponse:
    """End the session."""
    response = RedirectResponse("/login", status_code=303)
    web_session.log_out(page.svc, request, response)
    return response
