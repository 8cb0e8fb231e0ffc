"""Errors of the server's services; the API maps each to one HTTP status.

They sit under :class:`~opendnc.errors.DncError` like everything else opendnc raises, so a
script that drives the services directly catches them the same way as protocol errors.
"""

from __future__ import annotations

from opendnc.errors import DncError

__all__ = ["Conflict", "Forbidden", "NotFound", "Unauthorized"]


class NotFound(DncError):
    """The named program, version, job or machine does not exist (HTTP 404)."""


class Conflict(DncError):
    """The request is well-formed but the current state does not allow it (HTTP 409)."""


class Unauthorized(DncError):
    """No valid credentials came with the request (HTTP 401)."""


class Forbidden(DncError):
    """The credentials are valid but their role does not allow this (HTTP 403)."""
