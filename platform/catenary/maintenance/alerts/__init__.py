"""Maintenance alerts: the operator's wear limits evaluated on the fleet's span histories.

**Rules.** Each rule of the configured policy (``catenary.limits``, ``[limits]``) is a
residual thickness per wire type (``thresholds``). A ``local`` rule is met by a history
(``catenary.maintenance.history``: a span and wire across runs, from its last repair on) when the
span's
minimum residual thickness at its latest run reaches the threshold; an
``anchor_section_average`` rule by an anchor section when the samples-weighted mean residual
thickness of its spans, at the latest run that measured it, does. (That is the thickness of
the average, not the average worn fraction: where wear is concentrated in a few spans the
section's average worn fraction is somewhat higher.)

**Geometry.** The policy's geometry rules (``catenary.limits``: height, height gradient,
stagger, and the design stagger and height at each mast) on each history's latest span row
(``catenary.maintenance.alerts.geometry``), alerts of kind ``geometry``; resolved by a run back
within the limit by ``GEOMETRY_MARGIN_MM`` (2 mm) or by a maintenance action ``adjusted``
covering them. A span's line speed is the register's ``line_speed_kmh`` at its first mast, else
its line's in ``[maintenance] line_speed_kmh`` (``line_speeds``).

**Forecasts.** Each local rule also has a forecast (``catenary.maintenance.forecast``): the
history's wear
rate (least squares over its runs, with its standard error) and the date its line reaches the
threshold, with an interval from the rate's 95 % confidence interval. A forecast alert is
raised when that date falls within the planning horizon (``[maintenance] horizon_days``,
default 365 days from the evaluation) while the threshold is not met; it is resolved when
even the interval's earliest date lies beyond the horizon, or when the threshold is met (the
threshold alert takes over).

**Life cycle.** open -> acknowledged (by whom, when) -> resolved: by a later run whose value is
back above the threshold by ``RESOLVE_MARGIN_MM`` (so that noise at the threshold does not
open and close alerts in turn), by a repair covering it (``catenary.maintenance.actions``), or by
hand. A condition's ``condition_key`` is
``{kind}/{policy}#{rule}/t{track id}/w{position}/{stretch}/g{generation}``, the stretch being
``masts:{from}>{to}``, ``m:{start}>{end}`` (chainages, spans measured without a register) or
``section:{code}``; the generation counts the condition's earlier alerts, all resolved, so a
recurrence after a resolution is a new alert, raised only from a run that started after that
resolution (the repair's time, the resolving run's, or the moment it was resolved by hand).
An open or acknowledged alert is updated (latest value), never raised again, whatever runs are
evaluated in whatever order or twice; an evaluation that finds nothing new writes nothing.

**Scale.** One track at a time: its span measurements in one query (binary COPY on PostgreSQL,
``catenary.storage.columns``), then vectorised over its rows and histories; Python work is per
alert, never per span (``benchmarks/alerts_fleet.py``).
"""

from catenary.maintenance.alerts.evaluation import (
    RESOLVE_MARGIN_MM,
    Evaluation,
    RunAlerting,
    TrackFailure,
    evaluate_alerts,
    evaluate_all,
    evaluate_stored_run,
    evaluate_tracks,
    run_alerting,
    run_alerts_lines,
)
from catenary.maintenance.alerts.lifecycle import (
    ACTIVE,
    acknowledge_alert,
    alert_counts,
    alert_stretch,
    alert_summary,
    announce_alerts,
    due_forecasts,
    forecast_date,
    list_alerts,
    new_alerts_since,
    resolve_alert,
)
from catenary.maintenance.alerts.rules import (
    DEFAULT_HORIZON_DAYS,
    check_policy,
    horizon_days,
    line_speeds,
)

__all__ = [
    "ACTIVE",
    "DEFAULT_HORIZON_DAYS",
    "RESOLVE_MARGIN_MM",
    "Evaluation",
    "RunAlerting",
    "TrackFailure",
    "acknowledge_alert",
    "alert_counts",
    "alert_stretch",
    "alert_summary",
    "announce_alerts",
    "check_policy",
    "due_forecasts",
    "evaluate_alerts",
    "evaluate_all",
    "evaluate_stored_run",
    "evaluate_tracks",
    "forecast_date",
    "horizon_days",
    "line_speeds",
    "list_alerts",
    "new_alerts_since",
    "resolve_alert",
    "run_alerting",
    "run_alerts_lines",
]
