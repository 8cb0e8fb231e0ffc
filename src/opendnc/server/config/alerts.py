"""The ``[alerts]`` table of ``shop.toml``: rules, the e-mail target and the webhooks, typed and
checked (docs/server.md#alerts).

Example::

    [alerts]
    public_url = "https://dnc.example.com"    # optional: messages link to the machine's page

    [alerts.email]
    host = "smtp.example.com"
    port = 587
    starttls = true
    username = "dnc@example.com"              # optional login, with password
    password = "..."
    from = "dnc@example.com"
    to = ["supervisor@example.com"]

    [[alerts.webhooks]]
    name = "ops"
    url = "https://hooks.example.com/opendnc"
    secret = "..."                            # optional
    sign = "hmac"                             # X-Opendnc-Signature; "header": X-Opendnc-Secret

    [[alerts.rules]]
    name = "long-stop"
    when = "stopped"                          # alarm | stopped | offline | job_failed
    minutes = 10                              # how long the condition lasts before it alerts
    machines = ["mill-1", "vf2"]              # default: every machine
    send_to = ["email", "ops"]                # default: every target
    on_clear = true                           # one more message when it ends

Passwords and secrets are kept out of every ``repr`` (``field(repr=False)``), so neither a log
line nor an error that prints a configuration shows them.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from opendnc.server.core.configkeys import NAME, ConfigError, get_key, known_keys, port_range

__all__ = [
    "AlertKind",
    "AlertRule",
    "AlertsConfig",
    "EmailTarget",
    "Signing",
    "WebhookTarget",
    "parse_alerts",
]

EMAIL = "email"  # the e-mail target's name in a rule's send_to

# An address as SMTP carries it: no spaces, no angle brackets, one @ with a dot after it.
_ADDRESS = re.compile(r"^[^@\s<>,;]+@[^@\s<>,;]+\.[^@\s<>,;]+$")
_URL = re.compile(r"^https?://[^\s/?#]+(/[^\s]*)?$")


class AlertKind(enum.StrEnum):
    """What a rule watches for."""

    ALARM = "alarm"  # the control reports an alarm
    STOPPED = "stopped"  # a program stopped, interrupted or in feed hold
    OFFLINE = "offline"  # the server cannot reach the control
    JOB_FAILED = "job_failed"  # a job ended failed or interrupted


class Signing(enum.StrEnum):
    """How a webhook's receiver can tell the body came from this server."""

    NONE = "none"
    HEADER = "header"  # X-Opendnc-Secret: the secret itself
    HMAC = "hmac"  # X-Opendnc-Signature: sha256=HMAC-SHA256(secret, body), hex


@dataclass(frozen=True)
class AlertRule:
    """One rule: a condition on some machines, the targets it goes to."""

    name: str
    kind: AlertKind
    minutes: float = 0.0  # the condition lasts this long before it alerts (not job_failed)
    machines: frozenset[str] = frozenset()  # empty: every machine
    send_to: tuple[str, ...] = ()  # target names ("email", webhook names); empty: all
    on_clear: bool = False  # one more message when the condition ends

    def applies_to(self, machine: str) -> bool:
        """True if the rule watches ``machine``."""
        return not self.machines or machine in self.machines


@dataclass(frozen=True)
class EmailTarget:
    """An SMTP server and the addresses the alerts go to."""

    host: str
    sender: str
    to: tuple[str, ...]
    port: int = 25
    starttls: bool = False
    ssl: bool = False  # SMTP over TLS from the start (port 465)
    ca_file: Path | None = None  # a private CA for the server's certificate
    username: str = ""
    password: str = field(default="", repr=False)
    timeout: float = 10.0
    retries: int = 2  # more tries after the first, with backoff
    name: str = EMAIL

    def describe(self) -> str:
        """The target as the audit trail and the log name it (never the password)."""
        return f"email {','.join(self.to)} via {self.host}:{self.port}"


@dataclass(frozen=True)
class WebhookTarget:
    """An HTTP endpoint that gets each alert as a JSON POST."""

    name: str
    url: str = field(repr=False)  # its path or query may be a secret itself (chat webhooks)
    secret: str = field(default="", repr=False)
    sign: Signing = Signing.NONE
    timeout: float = 5.0
    retries: int = 2

    def describe(self) -> str:
        """The target as the audit trail and the log name it (its host only: a webhook's
        path is often its token)."""
        host = self.url.split("://", 1)[1].split("/", 1)[0].rsplit("@", 1)[-1]
        return f"webhook {self.name} ({host})"


@dataclass(frozen=True)
class AlertsConfig:
    """Every rule and target of ``[alerts]``."""

    rules: tuple[AlertRule, ...]
    email: EmailTarget | None = None
    webhooks: tuple[WebhookTarget, ...] = ()
    public_url: str = ""  # the dashboard's address as people reach it: links in messages
    queue: int = 1000  # alerts waiting per target; when it is full, the oldest are dropped
    backoff: float = 1.0  # seconds before the first retry, doubled each time

    @property
    def targets(self) -> tuple[EmailTarget | WebhookTarget, ...]:
        """Every target, e-mail first."""
        return ((self.email,) if self.email is not None else ()) + self.webhooks


def parse_alerts(table: dict[str, Any], base: Path, machines: set[str]) -> AlertsConfig:
    """``[alerts]`` checked against the configured ``machines``; :class:`ConfigError` names
    the first bad key (and never repeats a password or secret)."""
    known_keys(table, "alerts", {"public_url", "queue", "backoff", "email", "webhooks", "rules"})
    public_url = get_key(table, "alerts", "public_url", str, "").rstrip("/")
    if public_url and not _URL.match(public_url):
        raise ConfigError("alerts.public_url", "expected http://HOST[/PATH] or https://...")
    queue = get_key(table, "alerts", "queue", int, 1000)
    if not 1 <= queue <= 100_000:
        raise ConfigError("alerts.queue", "expected 1..100000 alerts")
    backoff = get_key(table, "alerts", "backoff", float, 1.0)
    if not 0.01 <= backoff <= 600:
        raise ConfigError("alerts.backoff", "expected seconds between 0.01 and 600")
    email = None
    if "email" in table:
        raw = table["email"]
        if not isinstance(raw, dict):
            raise ConfigError("alerts.email", "expected a table ([alerts.email])")
        email = _email(raw, base)
    webhooks = tuple(
        _webhook(item, f"alerts.webhooks[{i}]") for i, item in enumerate(_array(table, "webhooks"))
    )
    names = [EMAIL] if email is not None else []
    for i, hook in enumerate(webhooks):
        if hook.name in names:
            raise ConfigError(f"alerts.webhooks[{i}].name", f"{hook.name!r} is used twice")
        names.append(hook.name)
    if not names:
        raise ConfigError("alerts", "no target: add [alerts.email] or [[alerts.webhooks]]")
    rules = tuple(
        _rule(item, f"alerts.rules[{i}]", machines, names)
        for i, item in enumerate(_array(table, "rules"))
    )
    if not rules:
        raise ConfigError("alerts.rules", "no rule: add [[alerts.rules]]")
    seen: set[str] = set()
    for i, rule in enumerate(rules):
        if rule.name in seen:
            raise ConfigError(f"alerts.rules[{i}].name", f"{rule.name!r} is used twice")
        seen.add(rule.name)
    return AlertsConfig(rules, email, webhooks, public_url, queue, backoff)


def _array(table: dict[str, Any], key: str) -> list[dict[str, Any]]:
    value = table.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ConfigError(f"alerts.{key}", f"expected an array of tables ([[alerts.{key}]])")
    return value


def _tries(table: dict[str, Any], prefix: str, timeout: float) -> tuple[float, int]:
    seconds = get_key(table, prefix, "timeout", float, timeout)
    if not 0.1 <= seconds <= 120:
        raise ConfigError(f"{prefix}.timeout", "expected seconds between 0.1 and 120")
    retries = get_key(table, prefix, "retries", int, 2)
    if not 0 <= retries <= 10:
        raise ConfigError(f"{prefix}.retries", "expected 0..10 more tries")
    return seconds, retries


def _email(table: dict[str, Any], base: Path) -> EmailTarget:
    prefix = "alerts.email"
    known_keys(
        table,
        prefix,
        {"host", "port", "starttls", "ssl", "ca_file", "username", "password", "from", "to",
         "timeout", "retries"},
    )  # fmt: skip
    # the checks run in the order of the keys below, so the first bad key is the one named
    host, port, starttls, over_tls, ca_text = _email_server(table, prefix)
    username, password = _email_login(table, prefix, tls=starttls or over_tls)
    sender, to = _email_addresses(table, prefix)
    timeout, retries = _tries(table, prefix, 10.0)
    return EmailTarget(
        host=host,
        sender=sender,
        to=to,
        port=port,
        starttls=starttls,
        ssl=over_tls,
        ca_file=(base / ca_text).resolve() if ca_text else None,
        username=username,
        password=password,
        timeout=timeout,
        retries=retries,
    )


def _email_server(table: dict[str, Any], prefix: str) -> tuple[str, int, bool, bool, str]:
    """Where the SMTP server is and how the link is secured: host, port, starttls, ssl and
    the CA file's text (the port defaults to the one the TLS mode implies)."""
    host = get_key(table, prefix, "host", str, "")
    if not host or any(c.isspace() or c in "/@" for c in host):
        raise ConfigError(f"{prefix}.host", "expected the SMTP server's host name")
    starttls = get_key(table, prefix, "starttls", bool, False)
    over_tls = get_key(table, prefix, "ssl", bool, False)
    if starttls and over_tls:
        raise ConfigError(f"{prefix}.ssl", "use starttls (port 587) or ssl (port 465), not both")
    port = get_key(table, prefix, "port", int, 465 if over_tls else (587 if starttls else 25))
    port_range(port, f"{prefix}.port")
    ca_text = get_key(table, prefix, "ca_file", str, "")
    if ca_text and not (starttls or over_tls):
        raise ConfigError(f"{prefix}.ca_file", "a CA file is for TLS (starttls or ssl)")
    return host, port, starttls, over_tls, ca_text


def _email_login(table: dict[str, Any], prefix: str, *, tls: bool) -> tuple[str, str]:
    """The SMTP login (username, password), both or neither, and only over ``tls``."""
    username = get_key(table, prefix, "username", str, "")
    # a wrong type is named without its value: it may be the password
    if "password" in table and not isinstance(table["password"], str):
        raise ConfigError(f"{prefix}.password", "expected a string")
    password = str(table.get("password", ""))
    if password and not username:
        raise ConfigError(f"{prefix}.password", "a password needs a username")
    if username and not password:
        raise ConfigError(f"{prefix}.username", "a login needs a password")
    if password and not tls:
        # a login in clear text across the shop's network would give the password away
        raise ConfigError(f"{prefix}.password", "a login needs starttls or ssl")
    return username, password


def _email_addresses(table: dict[str, Any], prefix: str) -> tuple[str, tuple[str, ...]]:
    """The sender and the recipients (``to`` may be one address or a list)."""
    sender = get_key(table, prefix, "from", str, "")
    if not _ADDRESS.match(sender):
        raise ConfigError(f"{prefix}.from", f"expected an e-mail address, got {sender!r}")
    to_raw = table.get("to")
    if isinstance(to_raw, str):
        to_raw = [to_raw]
    if not isinstance(to_raw, list) or not to_raw:
        raise ConfigError(f"{prefix}.to", "expected a list of e-mail addresses")
    for i, address in enumerate(to_raw):
        if not isinstance(address, str) or not _ADDRESS.match(address):
            raise ConfigError(f"{prefix}.to[{i}]", f"expected an e-mail address, got {address!r}")
    return sender, tuple(to_raw)


def _webhook(table: dict[str, Any], prefix: str) -> WebhookTarget:
    known_keys(table, prefix, {"name", "url", "secret", "sign", "timeout", "retries"})
    name = get_key(table, prefix, "name", str, "")
    if not NAME.fullmatch(name) or name == EMAIL:
        raise ConfigError(f"{prefix}.name", "expected a short name (letters, digits, - _ .)")
    url = get_key(table, prefix, "url", str, "")
    if not _URL.match(url):
        # the URL itself is not repeated: a chat webhook's path is its token
        raise ConfigError(f"{prefix}.url", "expected http://HOST[:PORT]/PATH or https://...")
    port = re.match(r"^https?://(?:[^\s/?#@]*@)?[^\s/?#:]+:(\d+)(?:[/?#]|$)", url)
    if port is not None:
        port_range(int(port.group(1)), f"{prefix}.url")
    if "secret" in table and not isinstance(table["secret"], str):
        raise ConfigError(f"{prefix}.secret", "expected a string")
    secret = str(table.get("secret", ""))
    sign_text = get_key(table, prefix, "sign", str, "hmac" if secret else "none")
    try:
        sign = Signing(sign_text)
    except ValueError:
        raise ConfigError(f"{prefix}.sign", "expected hmac, header or none") from None
    if sign is not Signing.NONE and not secret:
        raise ConfigError(f"{prefix}.secret", f"sign = {sign.value!r} needs a secret")
    if secret and sign is Signing.NONE:
        raise ConfigError(f"{prefix}.sign", "a secret is sent as hmac or header, not none")
    timeout, retries = _tries(table, prefix, 5.0)
    return WebhookTarget(name, url, secret, sign, timeout, retries)


def _rule(table: dict[str, Any], prefix: str, machines: set[str], targets: list[str]) -> AlertRule:
    known_keys(table, prefix, {"name", "when", "minutes", "machines", "send_to", "on_clear"})
    name = get_key(table, prefix, "name", str, "")
    if not NAME.fullmatch(name):
        raise ConfigError(f"{prefix}.name", "expected a short name (letters, digits, - _ .)")
    when = get_key(table, prefix, "when", str, "")
    try:
        kind = AlertKind(when)
    except ValueError:
        raise ConfigError(
            f"{prefix}.when", f"expected {', '.join(k.value for k in AlertKind)}, got {when!r}"
        ) from None
    minutes = get_key(table, prefix, "minutes", float, 0.0)
    if kind is AlertKind.JOB_FAILED and "minutes" in table:
        raise ConfigError(f"{prefix}.minutes", "a failed job alerts at once: no minutes")
    if not 0 <= minutes <= 7 * 24 * 60:
        raise ConfigError(f"{prefix}.minutes", "expected 0 up to a week of minutes")
    on_clear = get_key(table, prefix, "on_clear", bool, False)
    if kind is AlertKind.JOB_FAILED and on_clear:
        raise ConfigError(f"{prefix}.on_clear", "a failed job does not clear")
    names = _names(table, prefix, "machines")
    for i, machine in enumerate(names):
        if machine not in machines:
            raise ConfigError(f"{prefix}.machines[{i}]", f"no machine named {machine!r}")
    send_to = _names(table, prefix, "send_to")
    for i, target in enumerate(send_to):
        if target not in targets:
            raise ConfigError(
                f"{prefix}.send_to[{i}]", f"no target {target!r} (have {', '.join(targets)})"
            )
    return AlertRule(name, kind, minutes, frozenset(names), tuple(send_to), on_clear)


def _names(table: dict[str, Any], prefix: str, key: str) -> list[str]:
    value = table.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{prefix}.{key}", "expected a list of names")
    if key in table and not value:
        raise ConfigError(f"{prefix}.{key}", "an empty list: leave the key out for all")
    return list(dict.fromkeys(value))
