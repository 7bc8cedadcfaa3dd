"""Assemble the rig for a session from a rig file: instrument drivers, sampler, cameras.

``open_bench(config, sim=...)`` returns a :class:`Bench` (a context manager) whatever the rig
is made of: real serial ports and cameras, or the simulated rig of :mod:`vfmlab.simrig`.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, field
from typing import Any

from acquisition import Sampler, open_load_cell, open_pressure
from acquisition.cameras import Camera, open_camera
from acquisition.protocol import RigConfig

__all__ = ["Bench", "BenchError", "open_bench", "check_identity"]

log = logging.getLogger(__name__)


class BenchError(RuntimeError):
    """The rig cannot be assembled (port, identity, camera); the message says which part."""


@dataclass
class Bench:
    """Everything the runner drives.

    Attributes
    ----------
    pressure, load_cell : instrument drivers
    sampler : Sampler (started)
    cameras : list of open Camera, in rig-file order
    stage : callable(stretch) or None (no motorised stage: the operator sets it)
    motor : ZaberStage or None (the rig file's ``[stage]``, opened, never moved here)
    operator_pressure : callable(Pa) or None (simulated operator's hand, for unattended manual mode)
    place_board, remove_board : callables or None (simulated hand with the calibration board)
    sim : SimBench or None
    """

    config: RigConfig
    pressure: Any
    load_cell: Any
    sampler: Any
    cameras: list[Camera]
    stage: Any = None
    operator_pressure: Any = None
    place_board: Any = None
    remove_board: Any = None
    sim: Any = None
    motor: Any = None
    _stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack, repr=False)

    def instruments(self) -> dict[str, dict[str, Any]]:
        """``instruments=`` for SessionWriter.create: identity and settings of both instruments."""
        return {"pressure": {"identity": self.pressure.identity, "settings": self.pressure.settings()},
                "load_cell": {"identity": self.load_cell.identity, "settings": self.load_cell.settings()}}

    def rig_record(self) -> dict[str, Any]:
        """``rig=`` for SessionWriter.create: the rig file as run and the cameras' read-back settings."""
        out = {"name": self.config.name, "config_text": self.config.text, "simulated": self.sim is not None,
               "cameras": [c.describe() for c in self.cameras]}
        if self.motor is not None:  # the motorised stage: port, microstep, soft limits, x0, gauge length
            out["stage"] = self.stage.settings() if hasattr(self.stage, "settings") else self.motor.settings()
        if self.config.window is not None:  # reconstruction.refraction.Window.from_dict reads it back
            out["window"] = self.config.window.to_dict()
        return out

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> Bench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def check_identity(role: str, expected_serial: str, identity: str) -> None:
    """Raise BenchError if ``expected_serial`` (non-empty) is not part of the instrument's identity."""
    if expected_serial and expected_serial not in identity:
        raise BenchError(f"{role}: expected the instrument with serial number {expected_serial!r}; "
                         f"the port answers {identity!r}")


def open_bench(config: RigConfig, sim: Any = None, *, rate_hz: float = 50.0) -> Bench:
    """Open the instruments, start the sampler and open the cameras of ``config``.

    Parameters
    ----------
    config : RigConfig
    sim : SimBench, entered, optional
        Required when a port is ``"sim"`` or a camera backend is ``"sim"``.
    """
    stack = contextlib.ExitStack()
    try:
        if config.simulated and sim is None:
            raise BenchError(f"{config.source}: the rig file names simulated ports ('sim'); run with --sim")
        p_port = sim.pressure_port if config.pressure.port == "sim" else config.pressure.port
        f_port = sim.load_cell_port if config.load_cell.port == "sim" else config.load_cell.port
        try:
            kw = {"baudrate": config.pressure.baudrate} if config.pressure.baudrate else {}
            pressure = open_pressure(p_port, **kw)
        except Exception as exc:
            raise BenchError(f"pressure instrument on {p_port}: {exc}") from exc
        stack.callback(pressure.close)
        check_identity("pressure", config.pressure.serial_number, pressure.identity)
        try:
            kw = {"baudrate": config.load_cell.baudrate} if config.load_cell.baudrate else {}
            load_cell = open_load_cell(f_port, **kw)
        except Exception as exc:
            raise BenchError(f"load cell on {f_port}: {exc}") from exc
        stack.callback(load_cell.close)
        check_identity("load cell", config.load_cell.serial_number, load_cell.identity)
        if config.pressure.mode == "controller" and not pressure.is_controller:
            raise BenchError(f"{config.source}: [pressure].mode = 'controller' but {pressure.identity!r} is an "
                             "indicator without Setpt; use mode = \"manual\"")
        factories = {"sim": sim.camera_factory} if sim is not None else None
        cameras = []
        for cc in config.cameras:
            cam = open_camera(cc.name, cc.backend, cc.settings, factories)
            try:
                cam.open()
            except Exception as exc:
                raise BenchError(f"camera {cc.name!r} ({cc.backend}): {exc}") from exc
            stack.callback(cam.close)
            cameras.append(cam)
        motor = _open_motor(config, sim, stack)
        sampler = Sampler(pressure, load_cell, rate_hz=rate_hz)
        sampler.start()
        stack.callback(sampler.stop)
        bench = Bench(config, pressure, load_cell, sampler, cameras,
                      stage=sim.set_stretch if sim is not None and motor is None else None,
                      operator_pressure=sim.set_operator_pressure if sim is not None else None,
                      place_board=sim.place_board if sim is not None else None,
                      remove_board=sim.remove_board if sim is not None else None, sim=sim, motor=motor,
                      _stack=stack)
        return bench
    except BaseException:
        stack.close()
        raise


def _open_motor(config: RigConfig, sim: Any, stack: contextlib.ExitStack) -> Any:
    """The rig file's ``[stage]`` (a Zaber axis), opened but not moved; None without one."""
    sc = config.stage
    if sc is None:
        return None
    from acquisition import StageSettings, open_zaber

    port = sim.stage_port if sc.port == "sim" else sc.port
    try:
        kw = {"baudrate": sc.baudrate} if sc.baudrate else {}
        motor = open_zaber(port, StageSettings(sc.microstep_m, sc.min_m, sc.max_m, sc.device, sc.axis), **kw)
    except Exception as exc:
        raise BenchError(f"stage on {port}: {exc}") from exc
    stack.callback(motor.close)
    check_identity("stage", sc.serial_number, str(port))
    return motor
