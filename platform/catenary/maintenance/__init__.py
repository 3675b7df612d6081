"""Condition-based maintenance: alerts, forecasts, histories, maintenance actions,
notifications, report requests and the scheduler's jobs and service."""
