"""Units at the edge of the configuration files, and the one error their parsers raise."""

from __future__ import annotations

MMHG = 133.322387415  # Pa
PRESSURE_UNITS: dict[str, float] = {"Pa": 1.0, "kPa": 1000.0, "mmHg": MMHG}


class ConfigError(ValueError):
    """A protocol, rig or specimen file is invalid; the message names the file and the key."""
