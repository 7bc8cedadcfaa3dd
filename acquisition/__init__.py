"""Acquisition: instruments, cameras, the session file and the operator's session runner.

This is the only stage that talks to hardware; it writes the HDF5 session file that the
other stages read (see ``docs/guide/session-format.md``).

The instrument names below are re-exported lazily (PEP 562): ``from acquisition import Sampler``
works as before, but commands that only read session files (``vfmlab identify``, ``info``) never
import the drivers or pyserial (~16 ms of start-up, ``benchmarks/bench_cli.py``).
"""

from __future__ import annotations

import importlib

#: public name -> module that defines it
_LAZY = {
    "Reading": "acquisition.driver_base",
    "DeviceError": "acquisition.instrument_errors",
    "Disconnected": "acquisition.instrument_errors",
    "GarbledReply": "acquisition.instrument_errors",
    "InstrumentError": "acquisition.instrument_errors",
    "InstrumentTimeout": "acquisition.instrument_errors",
    "open_load_cell": "acquisition.instruments",
    "open_pressure": "acquisition.instruments",
    "Mark10ForceGauge": "acquisition.mark10",
    "MensorPressure": "acquisition.mensor",
    "ChannelRecord": "acquisition.sampler",
    "ChannelStatus": "acquisition.sampler",
    "Sample": "acquisition.sampler",
    "Sampler": "acquisition.sampler",
    "SamplerEvent": "acquisition.sampler",
    "SerialLink": "acquisition.serial_link",
    "find_port_by_serial": "acquisition.serial_link",
    "StretchStage": "acquisition.stage",
    "position_from_stretch": "acquisition.stage",
    "stretch_from_position": "acquisition.stage",
    "StageFault": "acquisition.zaber",
    "StageNotHomed": "acquisition.zaber",
    "StageRejected": "acquisition.zaber",
    "StageSettings": "acquisition.zaber",
    "StageTravelError": "acquisition.zaber",
    "ZaberStage": "acquisition.zaber",
    "open_zaber": "acquisition.zaber",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'acquisition' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
