"""Opening the rig's two instruments from port specs (the entry points the session runner and CLI use)."""

from __future__ import annotations

from typing import Any, Callable

from acquisition.mark10 import Mark10ForceGauge, open_mark10
from acquisition.mensor import MensorPressure, open_mensor


def open_pressure(spec: Any, *, baudrate: int = 9600, timeout: float = 0.25, retries: int = 2,
                  list_ports: Callable[[], list] | None = None,
                  reconnect_interval: float = 0.5) -> MensorPressure:
    """Open the pressure transducer/controller (Mensor command set).

    Parameters
    ----------
    spec : str, callable or serial.SerialBase
        Port name/path, ``socket://host:port``, ``usb-serial:<serial number>``, a resolver callable,
        or an open pyserial port.
    baudrate : int
        Must match the instrument's remote-setup menu (pseudo-terminals and sockets ignore it).
    timeout : float
        Seconds allowed for one complete reply.
    retries : int
        Retries of a timed-out or garbled query before the error is raised.
    list_ports : callable, optional
        Port lister for ``usb-serial:`` specs (default ``serial.tools.list_ports.comports``).
    reconnect_interval : float
        Minimum seconds between attempts to re-open a vanished port.

    Returns
    -------
    MensorPressure
        Identity, unit and pressure type already read; nothing reconfigured.
    """
    return open_mensor(spec, baudrate=baudrate, timeout=timeout, retries=retries, list_ports=list_ports,
                       reconnect_interval=reconnect_interval)


def open_load_cell(spec: Any, *, baudrate: int = 115200, timeout: float = 0.25, retries: int = 2,
                   list_ports: Callable[[], list] | None = None, tension_positive: bool = True,
                   reconnect_interval: float = 0.5) -> Mark10ForceGauge:
    """Open the load cell indicator (Mark-10 command set); parameters as :func:`open_pressure`.

    ``tension_positive`` flips the gauge's compression-positive sign so tension reads positive (N).
    """
    return open_mark10(spec, baudrate=baudrate, timeout=timeout, retries=retries, list_ports=list_ports,
                       tension_positive=tension_positive, reconnect_interval=reconnect_interval)
