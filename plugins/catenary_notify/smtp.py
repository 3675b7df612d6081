"""The ``email`` notifier: one plain-text message an alert, sent over SMTP (``smtplib``).

Settings (``[notifications.channels.settings]``)::

    host = "smtp.example.org"
    port = 587                           # default: 587 starttls, 465 ssl, 25 none
    security = "starttls"                # starttls (default) | ssl | none
    allow_plain_auth = false             # log in over security = "none" (password in clear)
    ca_file = "/etc/ssl/certs/works-ca.pem"   # optional: the CA to trust (default: the system's)
    username = "catenary"                # optional: log in as
    password_env = "CATENARY_SMTP_PASSWORD"   # the environment variable holding the password
    from = "catenary@example.org"
    to = ["overhead-line@example.org"]
    timeout = 10                         # seconds, for each network operation

The password is never written in the file (``password`` is refused), and never sent in clear
unless the channel says so: a username with ``security = "none"`` is refused without
``allow_plain_auth = true``. A recipient the server
refuses while it accepts others is logged, not retried: a retry would repeat the message to
those who had it.
"""

from __future__ import annotations

import logging
import smtplib
import ssl
from collections.abc import Mapping
from dataclasses import dataclass
from email.message import EmailMessage
from email.utils import formatdate, make_msgid
from typing import Any

from catenary.plugins import AlertRecord
from catenary_notify import message
from catenary_notify.settings import (
    SettingsError,
    check_keys,
    from_environment,
    refuse_secret,
    seconds,
    text,
    variable_name,
)

log = logging.getLogger(__name__)

NAME = "email"
KEYS = {
    "host",
    "port",
    "security",
    "allow_plain_auth",
    "ca_file",
    "username",
    "password_env",
    "from",
    "to",
    "timeout",
}
DEFAULT_PORTS = {"starttls": 587, "ssl": 465, "none": 25}
DEFAULT_TIMEOUT_S = 10.0


def compose(alert: AlertRecord, sender: str, recipients: list[str]) -> EmailMessage:
    """The message of one alert."""
    mail = EmailMessage()
    mail["Subject"] = f"[catenary] {message.summary(alert)}"
    mail["From"] = sender
    mail["To"] = ", ".join(recipients)
    mail["Date"] = formatdate(usegmt=True)
    mail["Message-ID"] = make_msgid("catenary-alert", domain=sender.rpartition("@")[2] or None)
    mail.set_content(message.body(alert))
    return mail


def _recipients(settings: Mapping[str, Any]) -> list[str]:
    to = settings.get("to")
    if not isinstance(to, list) or not to or not all(isinstance(x, str) and x for x in to):
        raise SettingsError(f"{NAME} settings: to must be a list of addresses, not {to!r}")
    return to


@dataclass(frozen=True)
class _Options:
    """A channel's settings, checked (``options``)."""

    host: str
    port: int
    security: str
    sender: str
    recipients: list[str]
    timeout_s: float
    username: str | None
    ca_file: str | None


def options(settings: Mapping[str, Any]) -> _Options:
    """The settings as the config file holds them, checked; a ``SettingsError`` names the key.
    The password is not read (``send`` reads its variable)."""
    refuse_secret(NAME, settings, "password")
    check_keys(NAME, settings, KEYS)
    host = text(NAME, settings, "host")
    security = text(NAME, settings, "security", "starttls")
    if security not in DEFAULT_PORTS:
        raise SettingsError(
            f"{NAME} settings: security must be one of {', '.join(DEFAULT_PORTS)}, not {security!r}"
        )
    port = settings.get("port", DEFAULT_PORTS[security])
    if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
        raise SettingsError(f"{NAME} settings: port must be a port number, not {port!r}")
    sender = text(NAME, settings, "from")
    recipients = _recipients(settings)
    timeout_s = seconds(NAME, settings, "timeout", DEFAULT_TIMEOUT_S)
    username = settings.get("username")
    if username is not None and (not isinstance(username, str) or not username):
        raise SettingsError(f"{NAME} settings: username must be a string, not {username!r}")
    if username is None and "password_env" in settings:
        raise SettingsError(f"{NAME} settings: password_env is given without a username")
    if username is not None:
        variable_name(NAME, "password_env", settings.get("password_env"))
    allow_plain_auth = settings.get("allow_plain_auth", False)
    if not isinstance(allow_plain_auth, bool):
        raise SettingsError(
            f"{NAME} settings: allow_plain_auth must be true or false, not {allow_plain_auth!r}"
        )
    if security == "none" and username is not None and not allow_plain_auth:
        raise SettingsError(
            f'{NAME} settings: security = "none" with a username would send the password in '
            'clear: use "starttls" or "ssl", or set allow_plain_auth = true'
        )
    ca_file = settings.get("ca_file")
    if ca_file is not None and not isinstance(ca_file, str):
        raise SettingsError(f"{NAME} settings: ca_file must be a path, not {ca_file!r}")
    return _Options(host, port, security, sender, recipients, timeout_s, username, ca_file)


def check(settings: Mapping[str, Any]) -> None:
    """Refuse settings ``send`` would refuse whatever the environment (``Notifier.check``)."""
    options(settings)


def send(alert: AlertRecord, settings: Mapping[str, Any]) -> None:
    """Send ``alert`` as one message to the channel's recipients; raise on any failure."""
    checked = options(settings)
    host, port, security = checked.host, checked.port, checked.security
    sender, recipients, username = checked.sender, checked.recipients, checked.username
    password = None
    if username is not None:
        password = from_environment(NAME, "password_env", settings.get("password_env"))

    mail = compose(alert, sender, recipients)
    context = ssl.create_default_context(cafile=checked.ca_file)
    client: smtplib.SMTP
    if security == "ssl":
        client = smtplib.SMTP_SSL(host, port, timeout=checked.timeout_s, context=context)
    else:
        client = smtplib.SMTP(host, port, timeout=checked.timeout_s)
    with client:
        if security == "starttls":
            client.starttls(context=context)
        if username is not None and password is not None:
            client.login(username, password)
        refused = client.send_message(mail, from_addr=sender, to_addrs=recipients)
    for address, (code, reply) in refused.items():
        log.warning(
            "alert %s: %s refused recipient %s (%s %s)",
            alert["id"],
            host,
            address,
            code,
            reply.decode(errors="replace"),
        )
