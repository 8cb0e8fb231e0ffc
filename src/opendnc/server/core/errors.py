"""Errors of the server's services; the API maps each to one HTTP status.

They sit under :class:`~opendnc.errors.DncError` like everything else opendnc raises, so a
script that drives the services directly catches them the same way as protocol errors.
"""

from __future__ import annotations

from opendnc.errors import ControlRefused, DncError, InputError, SafetyLockError, TransportError

__all__ = [
    "Conflict",
    "Forbidden",
    "NotFound",
    "TooLarge",
    "TooManyRequests",
    "Unauthorized",
    "Unavailable",
    "http_status",
]


class NotFound(DncError):
    """The named program, version, job or machine does not exist (HTTP 404)."""


class Conflict(DncError):
    """The request is well-formed but the current state does not allow it (HTTP 409)."""


class Unauthorized(DncError):
    """No valid credentials came with the request (HTTP 401)."""


class Forbidden(DncError):
    """The credentials are valid but their role does not allow this (HTTP 403)."""


class Unavailable(DncError):
    """The machine or service the request needs cannot be reached now (HTTP 503)."""


class TooManyRequests(DncError):
    """Too many failed attempts from this user or address; try again later (HTTP 429)."""

    def __init__(self, message: str, retry_after: int) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class TooLarge(DncError):
    """The request's body is larger than the server takes (HTTP 413)."""


# One status per error, for the API and the pages alike (the first class that matches).
_STATUS: tuple[tuple[type[DncError], int], ...] = (
    (InputError, 400),
    (Unauthorized, 401),
    (Forbidden, 403),
    (NotFound, 404),
    (Conflict, 409),
    (ControlRefused, 409),  # the control said no (a missing file, a locked one)
    (SafetyLockError, 409),
    (TooLarge, 413),
    (TooManyRequests, 429),
    (Unavailable, 503),
    (TransportError, 503),  # the control cannot be reached
)


def http_status(exc: DncError) -> int:
    """The HTTP status that answers ``exc`` (500 for an error no request should cause)."""
    for cls, status in _STATUS:
        if isinstance(exc, cls):
            return status
    return 500
