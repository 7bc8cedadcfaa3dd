"""Protocol, rig-configuration and specimen files: TOML on disk -> frozen dataclasses in SI.

A protocol is data. Everything is validated before anything moves: an unknown key, a
pressure above the rig's safety limit, an empty block, an impossible stretch or a value of
the wrong type raises :class:`ConfigError` with one message naming the file and the key
(``paper-protocol.toml: [[block]] #2 .stretch: expected a number >= 1; got 0.9``).

Units live at the edge. A pressure may be given with its unit in the key
(``pressure_max_mmHg``, ``pressures_kPa``, ``band_Pa``) or without it plus a ``unit`` key in the
same table (``unit = "mmHg"``); lengths in specimen files are in mm (``radius_mm``). Inside
the dataclasses everything is SI: Pa, m, s; stretches are dimensionless ``L/L0``.

Protocol file layout (see ``examples/paper-protocol.toml``)::

    [protocol]          name, description
    [preconditioning]   pressure_cycles, pressure_max_<u>, stretch_cycles, stretch_max,
                        cycle_s, imaged
    [stability]         band_<u>, dwell_s, timeout_s
    [test]              stretches = [...], pressures_<u> = [...]    (same levels at each stretch)
    [[block]]           stretch, pressures_<u>                      (or explicit blocks)
    [capture]           cameras = ["all"] or names, timeout_s
    [calibration]       views (board poses captured before the test), board (description)
    [reference]         capture = true: first capture the stress-free reference state
                        (L/L0 = 1, p = 0) as block 0 (identification's reference step);
                        repeats = N (default 1, at most 20): capture it N times (N steps of
                        block 0), averaged into one reference by the identification

Modules, one concept each: ``_units`` (units, :class:`ConfigError`), ``_model`` (the protocol dataclasses), ``_rig_model`` (rig
and specimen dataclasses), ``_toml`` (reading TOML with precise errors), ``_protocol_file`` and
``_rig_file`` (the parsers). Code outside the package imports only the names below.
"""

from __future__ import annotations

from acquisition.protocol._model import (
    MAX_DURATION_S,
    MAX_REFERENCE_REPEATS,
    MIN_CYCLE_S,
    CalibrationViews,
    CaptureSettings,
    Preconditioning,
    Protocol,
    Stability,
    TestBlock,
)
from acquisition.protocol._protocol_file import load_protocol, parse_protocol
from acquisition.protocol._rig_file import load_rig, load_specimen, parse_rig, parse_specimen
from acquisition.protocol._rig_model import (
    END_CONDITIONS,
    MAX_CAMERAS,
    SIMULATED_MATERIALS,
    CameraConfig,
    PortConfig,
    RigConfig,
    SafetyLimits,
    SimFaults,
    SimulationConfig,
    SpecimenFile,
    StageConfig,
    WindowConfig,
)
from acquisition.protocol._units import MMHG, PRESSURE_UNITS, ConfigError

__all__ = [
    "ConfigError",
    "WindowConfig",
    "PRESSURE_UNITS",
    "Preconditioning",
    "Stability",
    "TestBlock",
    "CaptureSettings",
    "CalibrationViews",
    "Protocol",
    "PortConfig",
    "CameraConfig",
    "SafetyLimits",
    "RigConfig",
    "SpecimenFile",
    "load_protocol",
    "parse_protocol",
    "load_rig",
    "parse_rig",
    "load_specimen",
    "parse_specimen",
    "MMHG",
    "MAX_DURATION_S",
    "MAX_REFERENCE_REPEATS",
    "MIN_CYCLE_S",
    "MAX_CAMERAS",
    "END_CONDITIONS",
    "SIMULATED_MATERIALS",
    "SimulationConfig",
    "SimFaults",
    "StageConfig",
]
