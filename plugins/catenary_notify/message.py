"""The words of an alert notification: a one-line summary and a plain-text body."""

from __future__ import annotations

from catenary.plugins import AlertRecord


def mast_range(alert: AlertRecord) -> str:
    """``masts M1 to M2``, or the chainage when the alert has no masts."""
    start, end = alert.mast_from, alert.mast_to
    if start is None and end is None:
        return f"chainage {alert.start_chainage_m:.1f} to {alert.end_chainage_m:.1f} m"
    if start == end or end is None:
        return f"mast {start}"
    return f"masts {start} to {end}"


def summary(alert: AlertRecord) -> str:
    """One line: level (and kind, if not a threshold crossed), where, value against threshold."""
    level = str(alert.level).upper()
    if alert.kind != "threshold":
        level += f" ({alert.kind})"
    return (
        f"{level}: line {alert.line} track {alert.track}, {mast_range(alert)}, "
        f"wire position {alert.wire}: {alert.value:.3f} vs threshold {alert.threshold:.3f} "
        f"({alert.rule})"
    )


def body(alert: AlertRecord) -> str:
    """The plain-text message: every field a maintenance planner needs, one a line."""
    details = alert.details
    rows = [
        ("Level", alert.level),
        ("Line", alert.line),
        ("Track", alert.track),
        ("Masts", f"{alert.mast_from or '-'} to {alert.mast_to or '-'}"),
        (
            "Chainage",
            f"{alert.start_chainage_m:.1f} m to {alert.end_chainage_m:.1f} m",
        ),
        ("Position", alert.wire),
        ("Value", f"{alert.value:.3f} (threshold {alert.threshold:.3f})"),
        ("Kind", alert.kind),
        ("Rule", alert.rule),
        ("Raised at", alert.raised_at),
        ("Alert", f"{alert.id} ({alert.status})"),
    ]
    if details:
        rows.append(("Details", ""))
        rows.extend((f"  {key}", value) for key, value in sorted(details.items()))
    width = max(len(label) for label, _ in rows) + 1
    lines = [f"{label + ':':<{width}} {value}".rstrip() for label, value in rows]
    return f"catenary maintenance alert\n\n{summary(alert)}\n\n" + "\n".join(lines) + "\n"
