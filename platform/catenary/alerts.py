"""Deprecated: alerts are in ``catenary.maintenance.alerts``; an alert's record for plugins is
``catenary.plugins.AlertRecord.of(alert)``."""

from catenary.deprecated import moved
from catenary.plugins.types import AlertRecord

__all__ = ["alert_record"]

alert_record = AlertRecord.of

moved("catenary.alerts", "catenary.maintenance.alerts, and catenary.plugins.AlertRecord")
