"""Delivery of alert notifications: each alert to each channel that wants it, retried until sent.

Channels come from the config's ``[notifications]``; each names a notifier plugin (``email``,
``webhook``, ...), the alert levels it gets and the notifier's own settings::

    [notifications]
    max_attempts = 10                 # then a delivery stays failed (catenary notify status)
    retry_minutes = 1                 # wait before the first retry, doubled after each failure

    [[notifications.channels]]
    name = "maintenance-email"        # default: the notifier's name; unique
    notifier = "email"
    levels = ["urgent", "critical"]   # default: every level
    timeout_seconds = 60              # a send that has not returned by then has failed
    [notifications.channels.settings] # the notifier's settings
    host = "smtp.example.org"

A delivery is an ``AlertNotification`` row (its ``notifier`` column holds the channel's name).
``queue_notifications`` adds one, pending, for every open alert and channel that wants its level,
at most one per alert and channel; ``deliver_pending`` sends those that are due, outside any
transaction, and records every attempt. A row is never deleted: after ``max_attempts`` failures it
stays failed with its last error (raising ``max_attempts`` makes it due again, and
``requeue_failed``, ``catenary notify requeue``, queues it again from its first attempt).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import ColumnElement, and_, or_, select, update
from sqlalchemy.orm import Session, joinedload

from catenary.config import Settings
from catenary.errors import UserError, one_line
from catenary.limits import LEVELS
from catenary.plugins import PluginRegistry
from catenary.plugins.manager import PluginFailure, plugin_errors
from catenary.plugins.types import AlertRecord, Notifier
from catenary.storage.inserts import insert_new
from catenary.storage.models import NAME_LENGTH, Alert, AlertNotification, Track, utc_now

SessionFactory = Callable[[], AbstractContextManager[Session]]
Clock = Callable[[], datetime]

DEFAULT_MAX_ATTEMPTS = 10
DEFAULT_RETRY_MINUTES = 1.0
DEFAULT_TIMEOUT_SECONDS = 60.0
MAX_RETRY_DELAY = timedelta(days=1)
"""The longest wait between two attempts, however many failures came before."""
CLAIM_MARGIN = timedelta(minutes=1)
"""How long past its timeout a claimed delivery stays claimed (a pass that died mid-send)."""
ERROR_LENGTH = 2000
"""The characters of a failure's message kept in ``last_error``."""

_SECTION_KEYS = {"max_attempts", "retry_minutes", "channels"}
_CHANNEL_KEYS = {"name", "notifier", "levels", "timeout_seconds", "settings"}


@dataclass(frozen=True)
class Channel:
    """A configured destination: a notifier, its settings and the alert levels it gets."""

    name: str
    notifier: str
    levels: frozenset[str]
    settings: Mapping[str, Any]
    timeout_s: float = DEFAULT_TIMEOUT_SECONDS


@dataclass(frozen=True)
class NotificationConfig:
    """The ``[notifications]`` section."""

    channels: tuple[Channel, ...] = ()
    max_attempts: int = DEFAULT_MAX_ATTEMPTS
    retry_minutes: float = DEFAULT_RETRY_MINUTES

    def retry_delay(self, failures: int) -> timedelta:
        """The wait after the ``failures``-th failed attempt: doubling, at most a day."""
        longest = MAX_RETRY_DELAY / timedelta(minutes=1)
        return timedelta(minutes=min(self.retry_minutes * 2.0 ** min(failures - 1, 64), longest))


def _number(where: str, key: str, value: Any, *, integer: bool = False) -> float:
    wrong = isinstance(value, bool) or not isinstance(value, int | float)
    if wrong or value <= 0 or (integer and not isinstance(value, int)):
        kind = "a positive integer" if integer else "a positive number"
        raise UserError(f"{where}: {key} must be {kind}, not {value!r}")
    return float(value)


def _check_keys(where: str, key: str, table: Mapping[str, Any], known: set[str]) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        known_keys = ", ".join(sorted(known))
        raise UserError(f"{where}: unknown key {key}.{unknown[0]} (known: {known_keys})")


def _channel(where: str, number: int, item: Any) -> Channel:
    label = f"notifications.channels[{number}]"
    if not isinstance(item, dict):
        raise UserError(f"{where}: {label} must be a table ([[notifications.channels]])")
    _check_keys(where, label, item, _CHANNEL_KEYS)
    notifier = item.get("notifier")
    if not isinstance(notifier, str) or not notifier:
        raise UserError(f"{where}: {label}.notifier must name a notifier, not {notifier!r}")
    name = item.get("name", notifier)
    if not isinstance(name, str) or not 0 < len(name) <= NAME_LENGTH:
        raise UserError(
            f"{where}: {label}.name must be a string of 1 to {NAME_LENGTH} characters, not {name!r}"
        )
    levels = item.get("levels", list(LEVELS))
    if not isinstance(levels, list) or not levels or not all(x in LEVELS for x in levels):
        raise UserError(
            f"{where}: {label}.levels must be a list of {', '.join(LEVELS)}, not {levels!r}"
        )
    settings = item.get("settings", {})
    if not isinstance(settings, dict):
        raise UserError(f"{where}: {label}.settings must be a table, not {settings!r}")
    timeout = item.get("timeout_seconds", DEFAULT_TIMEOUT_SECONDS)
    timeout_s = _number(where, f"{label}.timeout_seconds", timeout)
    return Channel(name, notifier, frozenset(levels), settings, float(timeout_s))


def notification_config(
    settings: Settings, registry: PluginRegistry | None = None
) -> NotificationConfig:
    """The ``[notifications]`` section of ``settings``; a malformed one is a one-line
    ``UserError`` naming the config file and the key. With ``registry``, each channel's
    settings are checked by its notifier too (``Notifier.check``; a channel whose notifier is
    not installed waits, as in ``deliver_pending``): call it so when a command or service that
    may queue or send notifications starts, so that a wrong setting is refused then, not at
    every send."""
    where = str(settings.config_path or "config")
    section = settings.sections.get("notifications", {})
    if not isinstance(section, dict):
        raise UserError(f"{where}: [notifications] must be a table")
    _check_keys(where, "notifications", section, _SECTION_KEYS)
    max_attempts = section.get("max_attempts", DEFAULT_MAX_ATTEMPTS)
    _number(where, "notifications.max_attempts", max_attempts, integer=True)
    retry = section.get("retry_minutes", DEFAULT_RETRY_MINUTES)
    _number(where, "notifications.retry_minutes", retry)
    items = section.get("channels", [])
    if not isinstance(items, list):
        raise UserError(f"{where}: notifications.channels must be an array of tables")
    channels = tuple(_channel(where, number, item) for number, item in enumerate(items, 1))
    names = [channel.name for channel in channels]
    for name in names:
        if names.count(name) > 1:
            raise UserError(
                f"{where}: two notification channels are named {name!r}: give each a name"
            )
    if registry is not None:
        for channel in channels:
            _check_channel(where, channel, registry)
    return NotificationConfig(channels, int(max_attempts), float(retry))


def _check_channel(where: str, channel: Channel, registry: PluginRegistry) -> None:
    notifier = registry.notifiers().get(channel.notifier)
    if notifier is None or notifier.check is None:
        return
    with registry.boundary("notifier", channel.notifier):
        try:
            notifier.check(channel.settings)
        except ValueError as exc:
            message = " ".join(str(exc).split())
            raise UserError(f"{where}: notification channel {channel.name!r}: {message}") from None


def queue_notifications(session: Session, config: NotificationConfig) -> int:
    """Add a pending delivery for each open alert and each channel that wants its level and
    has none yet; return how many were found missing.

    Idempotent, and safe beside a concurrent call: on PostgreSQL and SQLite a delivery another
    transaction added first is left alone (``ON CONFLICT DO NOTHING``). Call it in the
    transaction that raises the alerts, or any time later.
    """
    found = 0
    for channel in config.channels:
        queued = (
            select(AlertNotification.id)
            .where(
                AlertNotification.alert_id == Alert.id,
                AlertNotification.notifier == channel.name,
            )
            .exists()
        )
        alert_ids = session.scalars(
            select(Alert.id)
            .where(Alert.status == "open", Alert.level.in_(sorted(channel.levels)), ~queued)
            .order_by(Alert.id)
        ).all()
        if alert_ids:
            rows = [{"alert_id": alert_id, "notifier": channel.name} for alert_id in alert_ids]
            insert_new(session, AlertNotification, rows, ["alert_id", "notifier"])
            found += len(rows)
    return found


@dataclass(frozen=True)
class Attempt:
    """One attempt of one delivery; ``error`` is None when it was sent."""

    notification_id: int
    alert_id: int
    channel: str
    attempts: int
    error: str | None
    next_attempt_at: datetime | None

    @property
    def sent(self) -> bool:
        return self.error is None

    @property
    def gave_up(self) -> bool:
        """Failed for the last time: no further attempt is due."""
        return self.error is not None and self.next_attempt_at is None


@dataclass(frozen=True)
class DeliveryReport:
    """What one pass of ``deliver_pending`` did."""

    queued: int
    attempts: list[Attempt] = field(default_factory=list)
    unavailable: dict[str, str] = field(default_factory=dict)
    """Channels whose notifier is not installed, with why: their deliveries wait."""


def send_bounded(notifier: Notifier, alert: AlertRecord, channel: Channel) -> str | None:
    """Call ``notifier.send`` for ``channel`` inside the plugins' error boundary, giving up
    after the channel's timeout; return None if it returned, else its error in one line.

    The send runs in a daemon thread: one that hangs is left behind (it may still deliver,
    and its delivery is then retried: at least once, never lost).
    """
    outcome: list[str | None] = []

    def target() -> None:
        try:
            with plugin_errors(f"notifier {notifier.name!r}"):
                notifier.send(alert, channel.settings)
        except PluginFailure as failure:
            outcome.append(failure.detail)
        except Exception as exc:  # an error the user can act on, said as it is
            outcome.append(one_line(exc))
        else:
            outcome.append(None)

    thread = threading.Thread(target=target, name=f"notify-{channel.name}", daemon=True)
    thread.start()
    thread.join(channel.timeout_s)
    if thread.is_alive():
        return f"timed out: {notifier.name!r} had not returned after {channel.timeout_s:g} s"
    if not outcome:
        return f"notifier {notifier.name!r} ended without returning"
    return outcome[0]


def _due(now: datetime, config: NotificationConfig, channels: list[str]) -> ColumnElement[bool]:
    return and_(
        AlertNotification.status != "sent",
        AlertNotification.attempts < config.max_attempts,
        AlertNotification.notifier.in_(channels),
        or_(AlertNotification.next_attempt_at.is_(None), AlertNotification.next_attempt_at <= now),
    )


def _attempt(
    notification_id: int,
    session_factory: SessionFactory,
    channels: Mapping[str, tuple[Channel, Notifier]],
    config: NotificationConfig,
    clock: Clock,
) -> Attempt | None:
    """Claim one delivery, send it and record the outcome; None if another pass claimed it."""
    with session_factory() as session:
        now = clock()
        row = session.get(AlertNotification, notification_id)
        if row is None:
            return None
        channel, notifier = channels[row.notifier]
        claim = (
            update(AlertNotification)
            .where(AlertNotification.id == notification_id, _due(now, config, [channel.name]))
            .values(next_attempt_at=now + timedelta(seconds=channel.timeout_s) + CLAIM_MARGIN)
        )
        if session.connection().execute(claim).rowcount != 1:
            return None
        alert = session.scalars(
            select(Alert)
            .where(Alert.id == row.alert_id)
            .options(joinedload(Alert.track).joinedload(Track.line))
        ).one()
        record = AlertRecord.of(alert)

    error = send_bounded(notifier, record, channel)

    with session_factory() as session:
        row = session.get_one(AlertNotification, notification_id)
        row.attempts += 1
        row.last_error = None if error is None else error[:ERROR_LENGTH]
        row.status = "sent" if error is None else "failed"
        row.next_attempt_at = None
        if error is not None and row.attempts < config.max_attempts:
            row.next_attempt_at = clock() + config.retry_delay(row.attempts)
        return Attempt(
            notification_id,
            row.alert_id,
            channel.name,
            row.attempts,
            error,
            row.next_attempt_at,
        )


def deliver_pending(
    session_factory: SessionFactory,
    registry: PluginRegistry,
    settings: Settings,
    clock: Clock = utc_now,
) -> DeliveryReport:
    """One delivery pass: queue what is missing, then send every delivery that is due.

    Due: not sent, fewer than ``max_attempts`` attempts, its channel configured with an
    installed notifier, and its backoff elapsed. Each delivery is claimed, sent outside any
    transaction (bounded by the channel's timeout) and its attempt recorded in a transaction
    of its own: a failure or a concurrent pass never loses nor doubles one, and one whose pass
    died mid-send is due again once its claim has expired (delivered at least once).
    ``session_factory()`` opens a unit of work (``lambda: session_scope(engine)``).
    """
    config = notification_config(settings, registry)
    notifiers = registry.notifiers()
    known = ", ".join(sorted(notifiers)) or "none"
    usable: dict[str, tuple[Channel, Notifier]] = {}
    unavailable: dict[str, str] = {}
    for channel in config.channels:
        if channel.notifier in notifiers:
            usable[channel.name] = (channel, notifiers[channel.notifier])
        else:
            unavailable[channel.name] = (
                f"notifier {channel.notifier!r} is not installed (known: {known})"
            )
    with session_factory() as session:
        queued = queue_notifications(session, config)
    with session_factory() as session:
        due = session.scalars(
            select(AlertNotification.id)
            .where(_due(clock(), config, list(usable)))
            .order_by(AlertNotification.id)
        ).all()
    report = DeliveryReport(queued, unavailable=unavailable)
    for notification_id in due:
        attempt = _attempt(notification_id, session_factory, usable, config, clock)
        if attempt is not None:
            report.attempts.append(attempt)
    return report


def requeue_failed(
    session: Session, *, channel: str | None = None, alert_id: int | None = None
) -> int:
    """Queue again the deliveries that gave up (failed, no attempt due: ``max_attempts`` used),
    of ``channel`` and ``alert_id`` if given: pending, no attempt, no error, due at once.
    Returns how many. A failed delivery still retried (or being sent) is left alone."""
    statement = update(AlertNotification).where(
        AlertNotification.status == "failed", AlertNotification.next_attempt_at.is_(None)
    )
    if channel is not None:
        statement = statement.where(AlertNotification.notifier == channel)
    if alert_id is not None:
        statement = statement.where(AlertNotification.alert_id == alert_id)
    values = {"status": "pending", "attempts": 0, "last_error": None, "updated_at": utc_now()}
    return int(session.connection().execute(statement.values(**values)).rowcount)


def undelivered(session: Session) -> list[AlertNotification]:
    """Deliveries not sent (pending or failed), oldest first, with their alerts loaded."""
    return list(
        session.scalars(
            select(AlertNotification)
            .where(AlertNotification.status != "sent")
            .options(
                joinedload(AlertNotification.alert).joinedload(Alert.track).joinedload(Track.line)
            )
            .order_by(AlertNotification.id)
        )
    )
