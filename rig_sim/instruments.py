"""The rig's two simulated instruments, served on pseudo-terminals (or loopback sockets) together.

``SimulatedRig`` wires a :class:`PressurePlant` (controller set-point or operator pressure, first-order
response), a :class:`ForceModel` (mechanics callback + offset + drift + noise), the Mensor and Mark-10
device models and one :class:`DeviceServer` each. Port paths are stable symlinks in a private temporary
directory (``<tmp>/by-id/...``) so unplug/replug keeps the path; ``list_ports()`` mimics
``serial.tools.list_ports.comports()`` for lookups by USB serial number.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from types import SimpleNamespace
from typing import Callable

import numpy as np

from rig_sim.instrument_physics import ForceModel, MechanicsFn, PressurePlant
from rig_sim.mark10_sim import Mark10Device
from rig_sim.mensor_sim import MensorDevice
from rig_sim.serial_server import DeviceServer, FaultInjector


class SimulatedRig:
    """Both simulated instruments, as a context manager.

    Parameters
    ----------
    transport : {"pty", "socket"}
        Pseudo-terminals (default) or ``socket://127.0.0.1:PORT``.
    pressure_source : {"controller", "manual"}
        "controller": a Mensor CPC that follows its ``Setpt`` in ``Mode control``; "manual": a CPG2500
        indicator reading a pressure the operator sets with :meth:`set_operator_pressure`.
    mechanics : callable, optional
        ``f(pressure_Pa, stretch) -> N`` wall force; default a smooth stand-in.
    clock : callable
        Time source for the physics (s).
    rng : numpy.random.Generator
        Seeds the noise of both instruments and the garbage bytes.
    tau_s, pressure_noise_pa, force_noise_n, force_offset_n, force_drift_n_per_s : float
        Plant time constant and the instruments' imperfections.
    stable_window_pa : float
        Window of the controller's ``Stable?``.
    load_cell_measures : {"wall", "total"}
        "total": the cell sits behind a closed cannula of lumen radius ``cannula_radius_m`` and reads
        ``F_wall - p * pi * r_i**2`` (docs/decisions/0003-load-cell.md).
    """

    def __init__(self, transport: str = "pty", pressure_source: str = "controller", *,
                 mechanics: MechanicsFn | None = None, clock: Callable[[], float] = time.monotonic,
                 rng: np.random.Generator | None = None, tau_s: float = 0.3, pressure_noise_pa: float = 2.0,
                 force_noise_n: float = 0.002, force_offset_n: float = 0.0, force_drift_n_per_s: float = 0.0,
                 stable_window_pa: float = 20.0, load_cell_measures: str = "wall",
                 cannula_radius_m: float = 1.5e-3, pressure_serial: str = "SIM0001",
                 load_cell_serial: str = "SIM1001", mark10_ack: str | None = None) -> None:
        if pressure_source not in ("controller", "manual"):
            raise ValueError(f"pressure_source must be 'controller' or 'manual'; got {pressure_source!r}")
        if load_cell_measures not in ("wall", "total"):
            raise ValueError(f"load_cell_measures must be 'wall' or 'total'; got {load_cell_measures!r}")
        self.load_cell_measures = load_cell_measures
        end_area = np.pi * cannula_radius_m**2 if load_cell_measures == "total" else 0.0
        rng = rng if rng is not None else np.random.default_rng(0)
        seeds = rng.integers(0, 2**63 - 1, size=4)
        self.transport = transport
        self.pressure_source = pressure_source
        self.clock = clock
        self.plant = PressurePlant(clock, tau_s=tau_s)
        self.force_model = ForceModel(self.plant, mechanics, offset_n=force_offset_n,
                                      drift_n_per_s=force_drift_n_per_s, noise_n=force_noise_n,
                                      end_area_m2=end_area,
                                      rng=np.random.default_rng(seeds[0]))
        self.mensor = MensorDevice(self.plant, controller=pressure_source == "controller",
                                   rng=np.random.default_rng(seeds[1]), noise_pa=pressure_noise_pa,
                                   stable_window_pa=stable_window_pa, serial_number=pressure_serial)
        self.mark10 = Mark10Device(self.force_model, serial_number=load_cell_serial, ack=mark10_ack)
        self.pressure_serial = pressure_serial
        self.load_cell_serial = load_cell_serial
        self._dir = tempfile.mkdtemp(prefix="vfmlab-sim-")
        os.makedirs(os.path.join(self._dir, "by-id"))
        self._servers = {
            "pressure": DeviceServer(self.mensor.handle, transport=transport, name="mensor-sim",
                                     link_path=os.path.join(self._dir, "by-id", f"usb-Mensor_{pressure_serial}"),
                                     rng=np.random.default_rng(seeds[2]),
                                     inject_device_error=self._mensor_error),
            "force": DeviceServer(self.mark10.handle, transport=transport, name="mark10-sim",
                                  link_path=os.path.join(self._dir, "by-id", f"usb-Mark-10_{load_cell_serial}"),
                                  rng=np.random.default_rng(seeds[3]),
                                  inject_device_error=self.mark10.inject_error),
        }
        self._started = False

    def _mensor_error(self, n: int) -> None:
        for _ in range(n):
            self.mensor.push_error("Simulated device error: over pressure")

    # -- life cycle ------------------------------------------------------------------------------
    def start(self) -> "SimulatedRig":
        for s in self._servers.values():
            s.start()
        self._started = True
        return self

    def close(self) -> None:
        if self._started:
            for s in self._servers.values():
                s.stop()
            self._started = False
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> "SimulatedRig":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- ports -----------------------------------------------------------------------------------
    @property
    def pressure_port(self) -> str:
        """Stable path (pty symlink) or socket URL of the Mensor."""
        return self._servers["pressure"].port

    @property
    def load_cell_port(self) -> str:
        """Stable path (pty symlink) or socket URL of the Mark-10."""
        return self._servers["force"].port

    def device_path(self, channel: str) -> str | None:
        """The current real device (``/dev/pts/N``) behind a channel, None while unplugged."""
        s = self._server(channel)
        return s.device_path if s.plugged else None

    def list_ports(self) -> list[SimpleNamespace]:
        """Like ``serial.tools.list_ports.comports()``: plugged simulated ports with their serial numbers."""
        out = []
        for channel, sn in (("pressure", self.pressure_serial), ("force", self.load_cell_serial)):
            s = self._servers[channel]
            if s.plugged:
                out.append(SimpleNamespace(device=s.device_path, serial_number=sn,
                                           description=f"simulated {s.name}"))
        return out

    # -- the physical world ----------------------------------------------------------------------
    def set_operator_pressure(self, pa: float) -> None:
        """Manual pressure source: move the pressure towards ``pa`` (first-order)."""
        self.plant.set_target(pa)

    def set_stretch(self, stretch: float) -> None:
        """Axial stretch of the specimen (dimensionless) seen by the mechanics callback."""
        if not np.isfinite(stretch) or stretch <= 0:
            raise ValueError(f"stretch must be a positive finite number; got {stretch}")
        self.force_model.stretch = float(stretch)

    def set_mechanics(self, mechanics: MechanicsFn) -> None:
        """Replace the wall-force model ``f(pressure_Pa, stretch) -> N`` (e.g. the exact artery mechanics)."""
        if not callable(mechanics):
            raise TypeError(f"mechanics must be callable f(pressure_Pa, stretch) -> N; got {type(mechanics).__name__}")
        self.force_model.mechanics = mechanics

    @property
    def setpoint_pa(self) -> float:
        """The controller's set-point (Pa), as last received over the wire."""
        return self.mensor.setpoint_pa

    @property
    def controller_mode(self) -> str:
        """The controller's mode: ``"STANDBY"``, ``"MEASURE"``, ``"CONTROL"`` or ``"VENT"``."""
        return self.mensor.mode

    @property
    def target_pa(self) -> float:
        """Where the pressure is heading (set-point, vent or operator value), Pa."""
        return self.plant.target

    def true_pressure(self) -> float:
        """Noise-free pressure now (Pa)."""
        return self.plant.pressure()

    def true_force(self) -> float:
        """Noise-free force on the cell now (N, tension positive; the wall force, or the total force with
        ``load_cell_measures="total"``), before offset, drift and tare."""
        return self.force_model.true_force()

    def true_wall_force(self) -> float:
        """Noise-free wall force now (N), whatever the cell measures."""
        return float(self.force_model.mechanics(self.plant.pressure(), self.force_model.stretch))

    # -- faults ----------------------------------------------------------------------------------
    def _server(self, channel: str) -> DeviceServer:
        if channel not in self._servers:
            raise ValueError(f"channel must be 'pressure' or 'force'; got {channel!r}")
        return self._servers[channel]

    def fault(self, channel: str) -> FaultInjector:
        """Fault injection for ``"pressure"`` or ``"force"``."""
        return self._server(channel).faults

    def n_requests(self, channel: str) -> int:
        """Command lines received so far by a simulated device."""
        return self._server(channel).n_requests
