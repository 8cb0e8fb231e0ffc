"""Users, roles, passwords and API keys.

Passwords are hashed with argon2id (argon2-cffi's defaults follow RFC 9106's recommendations).
API keys are 256-bit random tokens shown once; the database keeps only their SHA-256, which is
enough for a key of that strength (a slow hash protects guessable passwords, not random keys)
and lets a request be checked with one indexed look-up.

A key is checked in a read-only transaction: a request never writes for its key. Its use is
noted in memory and ``last_used`` written once a minute for every key at once
(:mod:`opendnc.server.access.key_use`). A web session is a key labelled :data:`SESSION_LABEL`; it is
valid only as the dashboard's cookie, never as ``Authorization: Bearer``, so it cannot escape
the session's expiry. Failed logins and unknown keys are counted by
:class:`opendnc.server.access.throttle.Throttle`, which never refuses a valid credential because of
someone else's failures.
"""

from __future__ import annotations

import hashlib
import os
import re
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta

from argon2 import PasswordHasher, profiles
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session, joinedload, sessionmaker

from opendnc.errors import InputError
from opendnc.server.access.key_use import KeyUse
from opendnc.server.core.errors import Conflict, NotFound, Unauthorized
from opendnc.server.store import audit
from opendnc.server.store.models import ApiKey, Role, User, utcnow

__all__ = [
    "KEY_CACHE_SECONDS",
    "KEY_PREFIX_CHARS",
    "LAST_USED_EVERY",
    "SESSION_LABEL",
    "KeyCache",
    "KeyCheck",
    "Principal",
    "authenticate_key",
    "check_key",
    "check_password",
    "create_key",
    "create_user",
    "dummy_hash",
    "find_user",
    "key_hash",
    "revoke_key",
    "revoke_session",
    "set_password",
    "touch",
]

KEY_PREFIX = "odk_"
KEY_PREFIX_CHARS = len(KEY_PREFIX) + 6  # what a key's row keeps of it, shown to people
SESSION_LABEL = "web session"  # the label of the keys behind the dashboard's cookies
LAST_USED_EVERY = timedelta(minutes=1)
_USER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}$")
# argon2id with RFC 9106's low-memory profile (3 passes, 64 MiB, 4 lanes): about a third of a
# CPU second a password. A test suite, which makes and checks hundreds, may ask for argon2's
# cheapest parameters with OPENDNC_PASSWORD_PROFILE=cheapest (never for a shop: such a hash
# is guessed fast). A hash made under one profile is checked under the other, and made again
# with the current one at the next login.
PASSWORD_PROFILES = {
    "rfc9106-low-memory": profiles.RFC_9106_LOW_MEMORY,
    "cheapest": profiles.CHEAPEST,
}


def _password_hasher() -> PasswordHasher:
    name = os.environ.get("OPENDNC_PASSWORD_PROFILE", "rfc9106-low-memory")
    if name not in PASSWORD_PROFILES:
        known = ", ".join(PASSWORD_PROFILES)
        raise InputError(f"OPENDNC_PASSWORD_PROFILE={name!r} is not one of: {known}")
    return PasswordHasher.from_parameters(PASSWORD_PROFILES[name])


_hasher = _password_hasher()


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
    """The user ``name`` if ``password`` is theirs; :class:`Unauthorized` otherwise.

    Every refusal costs one password verification, the same as a wrong password of a real
    user: an unknown name, a disabled user or one without a password is checked against
    :func:`dummy_hash`, so how long a refusal takes does not tell which names exist. The
    caller counts and audits the refusal (:func:`opendnc.server.actions.sessions.log_in`)."""
    user = session.scalar(select(User).where(User.name == name))
    usable = user is not None and bool(user.password_hash) and not user.disabled
    stored = user.password_hash if user is not None and usable else None
    try:
        ok = _hasher.verify(stored or dummy_hash(), password) and stored is not None
    except (VerificationError, InvalidHashError):
        ok = False
    if not ok or user is None:
        raise Unauthorized("wrong user name or password")
    if _hasher.check_needs_rehash(user.password_hash or ""):
        user.password_hash = _hasher.hash(password)
    return Principal(user.name, Role(user.role))


_dummy: tuple[PasswordHasher, str] | None = None


def dummy_hash() -> str:
    """A hash of a random password, made with the current profile (once per hasher): what a
    login for a name without a usable password is verified against."""
    global _dummy
    if _dummy is None or _dummy[0] is not _hasher:
        _dummy = (_hasher, _hasher.hash(secrets.token_urlsafe(24)))
    return _dummy[1]


def create_key(
    session: Session,
    user_name: str,
    role: Role,
    *,
    label: str = "",
    actor: str = "system",
    create_user_role: Role | None = None,
    action: str = "key.create",
    via: str | None = None,
    address: str | None = None,
) -> tuple[ApiKey, str]:
    """A new key for ``user_name``; returns the row and the key (shown once, never stored).

    With ``create_user_role`` a missing user is created first with that role (a service user
    without a password, the usual owner of a machine-to-machine key). ``action`` names the
    audit row (a web session's key is recorded as the ``login`` it is, ``via`` and
    ``address`` saying where it came from).
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
        prefix=key[:KEY_PREFIX_CHARS],
        key_hash=_key_hash(key),
        role=int(role),
        label=label,
    )
    session.add(row)
    session.flush()
    audit.record(
        session,
        actor,
        action,
        key_id=row.id,
        user=user_name,
        role=role.name.lower(),
        via=via,
        address=address,
    )
    return row, key


@dataclass(frozen=True)
class KeyCheck:
    """A key that is valid: who it stands for, and what its row says of its use."""

    who: Principal
    label: str
    created: datetime
    last_used: datetime | None


def check_key(session: Session, key: str, *, web: bool = False) -> KeyCheck:
    """Who ``key`` stands for (reads only); :class:`Unauthorized` if unknown or revoked.

    ``web`` says where the key came from: a web session's key is valid only as the cookie
    (``web=True``), every other key only as ``Authorization: Bearer``."""
    if not key.startswith(KEY_PREFIX) or len(key) > 128:
        raise Unauthorized("not an opendnc API key")
    row = session.scalar(
        select(ApiKey).where(ApiKey.key_hash == _key_hash(key)).options(joinedload(ApiKey.user))
    )
    if row is None or row.revoked is not None or row.user.disabled:
        raise Unauthorized("unknown or revoked API key")
    if web and row.label != SESSION_LABEL:
        raise Unauthorized("not a web session")  # an API key pasted into a cookie
    if not web and row.label == SESSION_LABEL:
        raise Unauthorized("a web session is not an API key; send a key made for the API")
    who = Principal(row.user.name, Role(min(row.role, row.user.role)), key_id=row.id)
    return KeyCheck(who, row.label, row.created, row.last_used)


def touch(session: Session, check: KeyCheck) -> bool:
    """Write the key's ``last_used`` if the stored one is older than :data:`LAST_USED_EVERY`
    (True if it wrote). The condition is in the UPDATE, so many requests at once write once."""
    now = utcnow()
    if check.last_used is not None and now - check.last_used < LAST_USED_EVERY:
        return False
    stale = now - LAST_USED_EVERY
    session.execute(
        update(ApiKey)
        .where(ApiKey.id == check.who.key_id)
        .where(or_(ApiKey.last_used.is_(None), ApiKey.last_used < stale))
        .values(last_used=now)
    )
    return True


def authenticate_key(session: Session, key: str) -> Principal:
    """The principal a bearer key stands for (:func:`check_key` and :func:`touch` in one
    transaction, for scripts and tests that hold one session)."""
    check = check_key(session, key)
    touch(session, check)
    return check.who


KEY_CACHE_SECONDS = 5.0  # how long a checked key is taken without reading it again


class KeyCache:
    """Keys checked in the last :data:`KEY_CACHE_SECONDS`, so a request does not read its key.

    Reading the key was a transaction of its own on every request, as much work as the
    request's own query; a dashboard asks every second or two with the same key. A key
    revoked through this server is forgotten at once (:meth:`forget`); one revoked by another
    server sharing the database stops working here within the cache's seconds. Unknown and
    revoked keys are never kept: a new key works at once. Bounded; per process.
    """

    def __init__(
        self,
        seconds: float = KEY_CACHE_SECONDS,
        size: int = 10_000,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.seconds = seconds
        self.size = size
        self.clock = clock
        self._checks: OrderedDict[tuple[str, bool], tuple[float, KeyCheck]] = OrderedDict()
        self._lock = threading.Lock()  # requests check keys on the loop and in worker threads

    def get(self, key: str, *, web: bool = False) -> KeyCheck | None:
        """The check of ``key`` if it is fresh enough."""
        entry = (_key_hash(key), web)
        with self._lock:
            found = self._checks.get(entry)
            if found is None:
                return None
            if self.clock() - found[0] > self.seconds:
                del self._checks[entry]
                return None
            return found[1]

    def put(self, key: str, check: KeyCheck, *, web: bool = False) -> None:
        """Keep a successful check of ``key``."""
        with self._lock:
            self._checks[(_key_hash(key), web)] = (self.clock(), check)
            self._checks.move_to_end((_key_hash(key), web))
            while len(self._checks) > self.size:
                self._checks.popitem(last=False)

    def forget(self, key_id: int | None = None) -> None:
        """Forget key ``key_id`` (revoked), or every key with None."""
        with self._lock:
            if key_id is None:
                self._checks.clear()
                return
            for entry in [e for e, (_t, c) in self._checks.items() if c.who.key_id == key_id]:
                del self._checks[entry]


def authenticate(
    reads: sessionmaker[Session],
    key: str,
    uses: KeyUse,
    cache: KeyCache | None = None,
    *,
    web: bool = False,
) -> KeyCheck:
    """Who ``key`` stands for: from ``cache`` if it was checked a moment ago, otherwise
    :func:`check_key` in a read-only transaction. The use is noted in ``uses``, which writes
    ``last_used`` once a minute for every key at once (never on the request's path)."""
    check = cache.get(key, web=web) if cache is not None else None
    if check is None:
        with reads() as session:
            check = check_key(session, key, web=web)
        if cache is not None:
            cache.put(key, check, web=web)
    uses.note(check.who.key_id)
    return check


def revoke_key(session: Session, key_id: int, *, actor: str) -> None:
    """Revoke a key for good; revoking twice is harmless."""
    row = session.get(ApiKey, key_id)
    if row is None:
        raise NotFound(f"no API key {key_id}")
    if row.revoked is None:
        row.revoked = utcnow()
        audit.record(session, actor, "key.revoke", key_id=key_id)


def revoke_session(session: Session, key: str) -> int | None:
    """Revoke the web session whose key is ``key`` (audited as its user's); its key id, or
    None if ``key`` is no session's (an API key is never revoked this way)."""
    row = session.scalar(
        select(ApiKey).where(ApiKey.key_hash == key_hash(key)).options(joinedload(ApiKey.user))
    )
    if row is None or row.label != SESSION_LABEL:
        return None
    revoke_key(session, row.id, actor=row.user.name)
    return row.id
