"""Logging in through the login page, as a browser does: the form first (its CSRF token and
cookie), then the POST (docs/server.md#throttling)."""

from __future__ import annotations

import re
from typing import Any

__all__ = ["log_in", "login_form_token"]

_TOKEN = re.compile(r'name="csrf" value="([^"]+)"')


def login_form_token(http: Any) -> str:
    """The CSRF token of the login form ``http`` (an httpx client) is served now."""
    page = http.get("/login")
    assert page.status_code == 200, page.text
    found = _TOKEN.search(page.text)
    assert found is not None, "the login form carries no CSRF token"
    return found.group(1)


def log_in(http: Any, user: str, password: str, next: str = "/", **extra: Any) -> Any:
    """POST the login form as ``user`` (the reply, not followed)."""
    token = login_form_token(http)
    return http.post(
        "/login",
        data={"username": user, "password": password, "next": next, "csrf": token},
        follow_redirects=False,
        **extra,
    )
