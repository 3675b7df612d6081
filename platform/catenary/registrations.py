"""Deprecated: the registration types are in ``catenary.plugins``."""

from catenary.deprecated import moved
from catenary.plugins.types import (
    BlockProcessor,
    Command,
    Notifier,
    Processor,
    Reporter,
    ScanStream,
    Source,
    VehicleSource,
    VehicleStream,
)

__all__ = [
    "BlockProcessor",
    "Command",
    "Notifier",
    "Processor",
    "Reporter",
    "ScanStream",
    "Source",
    "VehicleSource",
    "VehicleStream",
]

moved("catenary.registrations", "catenary.plugins")
