"""What an alert says and how it gets there: the e-mail, the webhook's JSON body, and one try
of each (docs/server.md#alerts).

The webhook body is :class:`AlertBody`, version 1; its fields are documented in
docs/server.md#alerts and do not change meaning within a version. A signed body carries
``X-Opendnc-Signature: sha256=<hex HMAC-SHA256 of the raw body with the secret>``; a
receiver recomputes it over the bytes it read before parsing them.

No message here ever contains a password or a secret: errors are built from the exception's
type and text with the target's password, secret and URL taken out (:func:`scrub`).
"""

from __future__ import annotations

import hashlib
import hmac
import json
import smtplib
import ssl
from dataclasses import asdict, dataclass
from datetime import datetime
from email.message import EmailMessage
from email.utils import formatdate, make_msgid
from typing import TYPE_CHECKING, Any

from opendnc.errors import DncError
from opendnc.server.alerts.rules import Alert, Phase
from opendnc.server.config.alerts import AlertKind, EmailTarget, Signing, WebhookTarget
from opendnc.server.core.shifts import Calendar

if TYPE_CHECKING:
    import httpx

__all__ = [
    "SIGNATURE_HEADER",
    "AlertBody",
    "DeliveryError",
    "body_of",
    "email_of",
    "post_webhook",
    "scrub",
    "send_email",
    "sign",
]

SIGNATURE_HEADER = "X-Opendnc-Signature"
SECRET_HEADER = "X-Opendnc-Secret"
BODY_VERSION = 1

_WHAT = {
    AlertKind.ALARM: ("in alarm", "no longer in alarm"),
    AlertKind.STOPPED: ("stopped", "no longer stopped"),
    AlertKind.OFFLINE: ("offline", "online again"),
    AlertKind.JOB_FAILED: ("job failed", ""),
}


class DeliveryError(DncError):
    """An alert did not reach its target (the message never holds a password or secret)."""


@dataclass(frozen=True)
class AlertBody:
    """The JSON a webhook gets for one alert (version 1)."""

    version: int
    server: str  # the server that sent it ([server] name)
    rule: str
    kind: str  # alarm, stopped, offline, job_failed
    phase: str  # fired (the condition began), cleared (it ended)
    machine: str
    since: str  # when the condition began, ISO 8601 in UTC
    since_local: str  # the same instant on the shop's clock, with its offset
    timezone: str  # the shop's zone ([server] timezone)
    at: str  # when the alert was raised, ISO 8601 in UTC
    text: str  # one line for people: "mill-1 in alarm since 2026-11-29 09:02 (Europe/Berlin)"
    detail: str  # what the control said (alarm text, execution, the job's error)
    job_id: int | None
    program: str | None
    url: str | None  # the machine's page, when [alerts] public_url is set

    def as_json(self) -> dict[str, Any]:
        """The body as a dict (what :func:`json.dumps` sends)."""
        return asdict(self)

    def encode(self) -> bytes:
        """The bytes posted (and signed)."""
        return json.dumps(self.as_json(), ensure_ascii=False, separators=(",", ":")).encode()


def machine_url(public_url: str, machine: str) -> str | None:
    """The machine's page on the dashboard, when the public address is configured."""
    return f"{public_url}/machines/{machine}" if public_url else None


def headline(alert: Alert, calendar: Calendar) -> str:
    """The alert in one line, its time on the shop's clock with the zone named."""
    started, ended = _WHAT[alert.kind]
    since = f"{calendar.local(alert.since):%Y-%m-%d %H:%M} ({calendar.zone_name})"
    if alert.kind is AlertKind.JOB_FAILED:
        what = f"job {alert.job_id}" + (f" ({alert.program})" if alert.program else "")
        return f"{alert.machine}: {what} failed at {since}"
    if alert.phase is Phase.CLEARED:
        return f"{alert.machine} {ended} (was {started} since {since})"
    return f"{alert.machine} {started} since {since}"


def body_of(alert: Alert, calendar: Calendar, server: str, public_url: str) -> AlertBody:
    """The webhook body of ``alert``."""
    return AlertBody(
        version=BODY_VERSION,
        server=server,
        rule=alert.rule.name,
        kind=alert.kind.value,
        phase=alert.phase.value,
        machine=alert.machine,
        since=alert.since.isoformat(),
        since_local=calendar.local(alert.since).isoformat(),
        timezone=calendar.zone_name,
        at=alert.at.isoformat(),
        text=headline(alert, calendar),
        detail=alert.detail,
        job_id=alert.job_id,
        program=alert.program,
        url=machine_url(public_url, alert.machine),
    )


def email_of(body: AlertBody, target: EmailTarget) -> EmailMessage:
    """The e-mail of one alert: the headline as subject, the facts in the text."""
    message = EmailMessage()
    message["Subject"] = f"[opendnc] {body.text}"
    message["From"] = target.sender
    message["To"] = ", ".join(target.to)
    message["Date"] = formatdate(localtime=False)
    # the sender's domain, not the host's name: make_msgid would look that up (DNS)
    message["Message-ID"] = make_msgid("opendnc", domain=target.sender.rsplit("@", 1)[1])
    since = datetime.fromisoformat(body.since_local)
    lines = [
        body.text,
        "",
        f"Machine: {body.machine}",
        f"What:    {_WHAT[AlertKind(body.kind)][1 if body.phase == Phase.CLEARED else 0]}",
        f"Since:   {since:%Y-%m-%d %H:%M:%S} {body.timezone}",
    ]
    if body.phase == Phase.CLEARED:
        until = datetime.fromisoformat(body.at).astimezone(since.tzinfo)
        lines.append(f"Until:   {until:%Y-%m-%d %H:%M:%S} {body.timezone}")
    if body.detail:
        lines.append(f"Detail:  {body.detail}")
    if body.job_id is not None:
        lines.append(f"Job:     {body.job_id}" + (f" ({body.program})" if body.program else ""))
    if body.url:
        lines.append(f"Page:    {body.url}")
    lines += ["", f"Rule {body.rule!r} on server {body.server}."]
    message.set_content("\n".join(lines) + "\n")
    return message


def scrub(text: str, *secrets: str) -> str:
    """``text`` with every non-empty ``secrets`` replaced by ``***``."""
    for secret in secrets:
        if secret:
            text = text.replace(secret, "***")
    return text


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if isinstance(exc, DeliveryError) else f"{type(exc).__name__}: {text}"


def send_email(target: EmailTarget, message: EmailMessage) -> None:
    """Send ``message`` through the target's SMTP server (blocking: run it in a thread);
    :class:`DeliveryError` when it does not go."""
    try:
        context = ssl.create_default_context(cafile=str(target.ca_file) if target.ca_file else None)
        smtp: smtplib.SMTP
        if target.ssl:
            smtp = smtplib.SMTP_SSL(
                target.host, target.port, timeout=target.timeout, context=context
            )
        else:
            smtp = smtplib.SMTP(target.host, target.port, timeout=target.timeout)
        with smtp:
            if target.starttls:
                smtp.starttls(context=context)
            if target.username:
                smtp.login(target.username, target.password)
            refused = smtp.send_message(message)
        if refused:
            raise DeliveryError(f"refused for {', '.join(sorted(refused))}")
    except (OSError, smtplib.SMTPException, DeliveryError) as exc:
        # smtplib's errors carry the server's answer, never what we sent; scrubbed anyway
        raise DeliveryError(scrub(_one_line(exc), target.password)) from None


def sign(secret: str, body: bytes) -> str:
    """The signature header's value for ``body``: ``sha256=`` and the hex HMAC."""
    return "sha256=" + hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()


async def post_webhook(client: httpx.AsyncClient, target: WebhookTarget, body: bytes) -> None:
    """POST ``body`` to the webhook once; :class:`DeliveryError` unless it answers 2xx."""
    import httpx

    headers = {"Content-Type": "application/json", "User-Agent": "opendnc-alerts"}
    if target.sign is Signing.HMAC:
        headers[SIGNATURE_HEADER] = sign(target.secret, body)
    elif target.sign is Signing.HEADER:
        headers[SECRET_HEADER] = target.secret
    try:
        answer = await client.post(
            target.url, content=body, headers=headers, timeout=target.timeout
        )
    except httpx.HTTPError as exc:
        raise DeliveryError(scrub(_one_line(exc), target.url, target.secret)) from None
    if not 200 <= answer.status_code < 300:
        raise DeliveryError(f"HTTP {answer.status_code}")
