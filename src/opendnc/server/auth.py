"""Users, roles, passwords and API keys.

Passwords are hashed with argon2id (argon2-cffi's defaults follow RFC 9106's recommendations).
API keys are 256-bit random tokens shown once; the database keeps only their SHA-256, which is
enough for a key of that strength (a slow hash protects guessable passwords, not random keys)
and lets a request be checked with one indexed look-up.
"""

from __future__ import annotations

import hashlib
import re
import secrets
from dataclasses import dataclass

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.errors import InputError
from opendnc.server import audit
from opendnc.server.errors import Conflict, NotFound, Unauthorized
from opendnc.server.store.models import ApiKey, Role, User, utcnow

__all__ = [
    "Principal",
    "authenticate_key",
    "check_password",
    "create_key",
    "create_user",
    "find_user",
    "key_hash",
    "revoke_key",
    "set_password",
]

KEY_PREFIX = "odk_"
_USER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}$")
_hasher = PasswordHasher()


@dataclass(frozen=True)
class Principal:
    """Who is asking, and with which role (a key's role never exceeds its user's)."""

    name: str
    role: Role
    key_id: int | None = None

    def can(self, needed: Role) -> bool:
        """True if this principal's role includes ``needed``."""
        return self.role >= needed


def _key_hash(key: str) -> str:
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def key_hash(key: str) -> str:
    """The stored form of an API key (its SHA-256 in hex)."""
    return _key_hash(key)


def create_user(
    session: Session, name: str, role: Role, *, password: str | None = None, actor: str = "system"
) -> User:
    """Add a user; :class:`Conflict` if the name is taken."""
    if not _USER_NAME.fullmatch(name):
        raise InputError(f"user name {name!r}: use letters, digits, '.', '_', '@' or '-'")
    if session.scalar(select(User).where(User.name == name)) is not None:
        raise Conflict(f"user {name!r} exists already")
    if password is not None and len(password) < 8:
        raise InputError("a password needs at least 8 characters")
    user = User(
        name=name,
        role=int(role),
        password_hash=_hasher.hash(password) if password is not None else None,
    )
    session.add(user)
    session.flush()
    audit.record(session, actor, "user.create", user=name, role=role.name.lower())
    return user


def find_user(session: Session, name: str) -> User | None:
    """The user called ``name``, if there is one."""
    return session.scalar(select(User).where(User.name == name))


def set_password(session: Session, name: str, password: str, *, actor: str) -> User:
    """Give ``name`` a new password (audited)."""
    user = find_user(session, name)
    if user is None:
        raise NotFound(f"no user named {name!r}")
    if len(password) < 8:
        raise InputError("a password needs at least 8 characters")
    user.password_hash = _hasher.hash(password)
    audit.record(session, actor, "user.password", user=name)
    return user


def check_password(session: Session, name: str, password: str) -> Principal:
    """The user ``name`` if ``password`` is theirs; :class:`Unauthorized` otherwise (audited)."""
    user = session.scalar(select(User).where(User.name == name))
    ok = False
    if user is not None and user.password_hash and not user.disabled:
        try:
            ok = _hasher.verify(user.password_hash, password)
        except (VerificationError, InvalidHashError):
            ok = False
    audit.record(session, name, "login", result="ok" if ok else "refused")
    if not ok or user is None:
        raise Unauthorized("wrong user name or password")
    if _hasher.check_needs_rehash(user.password_hash or ""):
        user.password_hash = _hasher.hash(password)
    return Principal(user.name, Role(user.role))


def create_key(
    session: Session,
    user_name: str,
    role: Role,
    *,
    label: str = "",
    actor: str = "system",
    create_user_role: Role | None = None,
) -> tuple[ApiKey, str]:
    """A new key for ``user_name``; returns the row and the key (shown once, never stored).

    With ``create_user_role`` a missing user is created first with that role (a service user
    without a password, the usual owner of a machine-to-machine key).
    """
    user = session.scalar(select(User).where(User.name == user_name))
    if user is None:
        if create_user_role is None:
            raise NotFound(f"no user named {user_name!r}")
        user = create_user(session, user_name, create_user_role, actor=actor)
    if role > Role(user.role):
        raise InputError(
            f"a key cannot have more rights than its user ({user_name} is "
            f"{Role(user.role).name.lower()})"
        )
    key = KEY_PREFIX + secrets.token_urlsafe(32)
    row = ApiKey(
        user_id=user.id,
        prefix=key[: len(KEY_PREFIX) + 6],
        key_hash=_key_hash(key),
        role=int(role),
        label=label,
    )
    session.add(row)
    session.flush()
    audit.record(
        session, actor, "key.create", key_id=row.id, user=user_name, role=role.name.lower()
    )
    return row, key


def authenticate_key(session: Session, key: str) -> Principal:
    """The principal a bearer key stands for; :class:`Unauthorized` if unknown or revoked."""
    if not key.startswith(KEY_PREFIX) or len(key) > 128:
        raise Unauthorized("not an opendnc API key")
    row = session.scalar(select(ApiKey).where(ApiKey.key_hash == _key_hash(key)))
    if row is None or row.revoked is not None or row.user.disabled:
        raise Unauthorized("unknown or revoked API key")
    row.last_used = utcnow()
    return Principal(row.user.name, Role(min(row.role, row.user.role)), key_id=row.id)


def revoke_key(session: Session, key_id: int, *, actor: str) -> None:
    """Revoke a key for good; revoking twice is harmless."""
    row = session.get(ApiKey, key_id)
    if row is None:
        raise NotFound(f"no API key {key_id}")
    if row.revoked is None:
        row.revoked = utcnow()
        audit.record(session, actor, "key.revoke", key_id=key_id)
