"""Deprecated: report requests are made by ``catenary.maintenance.reports.report_request``."""

from catenary.deprecated import moved
from catenary.maintenance.reports import report_request

__all__ = ["report_request"]

moved("catenary.report_command", "catenary.maintenance.reports")
