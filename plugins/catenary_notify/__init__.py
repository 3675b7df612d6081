"""Built-in alert notifiers: ``email`` (SMTP) and ``webhook`` (a JSON POST).

The core's delivery (``catenary.maintenance.notifications``) calls ``send(alert, settings)``
with an alert's ``AlertRecord`` (``catenary.plugins``) and a channel's settings
(``[notifications.channels.settings]``); ``send`` returns once the alert is handed over and
raises otherwise, so the core records the failure and retries later; ``check(settings)`` refuses
what the config file holds wrong (a key, a URL, a port) when the core reads the configuration,
before any send. Secrets never live in the config file: settings name the environment
variables that hold them, read at send time.
"""

from __future__ import annotations

from catenary.plugins import hookimpl
from catenary.plugins.types import Notifier
from catenary_notify import smtp, webhook


@hookimpl
def catenary_notifiers() -> list[Notifier]:
    return [
        Notifier(
            name="email",
            description="e-mail over SMTP (STARTTLS, SSL or plain): a plain-text message an alert",
            send=smtp.send,
            check=smtp.check,
        ),
        Notifier(
            name="webhook",
            description="a JSON POST of the alert to a URL; any answer but 2xx is a failure",
            send=webhook.send,
            check=webhook.check,
        ),
    ]
