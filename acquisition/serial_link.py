"""A line-oriented serial link with robust I/O: the transport under the instrument drivers.

The link owns one pyserial port, opened from a *spec*:

* a port name or path (``"/dev/ttyUSB0"``, ``"COM3"``, a stable symlink such as ``/dev/serial/by-id/...``),
* a pyserial URL (``"socket://127.0.0.1:5000"``),
* ``"usb-serial:<serial number>"``: looked up with :func:`find_port_by_serial` on every (re)connect, so a
  re-enumerated USB adapter is found again under its new name,
* a zero-argument callable returning one of the above (a custom resolver),
* an already open :class:`serial.SerialBase` (reconnect then closes and re-opens that same object).

Reads go to the terminator; a reply without its terminator at the deadline is a timeout (the partial bytes
are kept on the exception). Any OS/pyserial error on the port means :class:`Disconnected`: the link closes
the port and re-opens it (re-resolving the spec) on a later call, at most every ``reconnect_interval`` s.
"""

from __future__ import annotations

import logging
import termios
import threading
import time
from typing import Any, Callable

import serial
import serial.tools.list_ports

from acquisition.instrument_errors import Disconnected, GarbledReply, InstrumentError, InstrumentTimeout

log = logging.getLogger(__name__)

USB_SERIAL_PREFIX = "usb-serial:"
_PORT_ERRORS = (serial.SerialException, OSError, termios.error, ValueError)


def find_port_by_serial(serial_number: str, list_ports: Callable[[], list] | None = None) -> str:
    """Return the device name of the serial port whose USB serial number is ``serial_number``.

    Parameters
    ----------
    serial_number : str
        USB serial number as reported by ``serial.tools.list_ports`` (``ListPortInfo.serial_number``).
    list_ports : callable, optional
        Returns port-info objects with ``.device`` and ``.serial_number``; default
        ``serial.tools.list_ports.comports`` (injectable for tests and simulators).

    Raises
    ------
    Disconnected
        No port with that serial number is present (adapter unplugged).
    """
    lister = list_ports or serial.tools.list_ports.comports
    ports = list(lister())
    matches = [p.device for p in ports if getattr(p, "serial_number", None) == serial_number]
    if not matches:
        seen = sorted(str(getattr(p, "serial_number", None)) for p in ports)
        raise Disconnected(f"no serial port with USB serial number {serial_number!r}; present: {seen}")
    if len(matches) > 1:
        log.warning("several ports with USB serial number %r: %s; using %s", serial_number, matches, matches[0])
    return matches[0]


class SerialLink:
    """Line-oriented, reconnecting access to one serial port.

    Parameters
    ----------
    spec : str, callable or serial.SerialBase
        Where the device is (see the module docstring).
    name : str
        Instrument name used in error messages and logs.
    baudrate : int
        Ignored by pseudo-terminals and sockets; must match the device menu on real hardware.
    timeout : float
        Seconds to wait for a complete reply line.
    terminator : bytes
        End of a reply line.
    line_ending : bytes
        Appended to every command sent.
    reconnect_interval : float
        Minimum seconds between two attempts to re-open a vanished port.
    max_line : int
        A reply longer than this without terminator is garbage.
    list_ports : callable, optional
        Port lister for ``usb-serial:`` specs.
    on_reconnect : callable, optional
        Called (without arguments) after the port has been re-opened; drivers re-confirm settings there.
    clock : callable
        Monotonic clock (s).
    """

    def __init__(self, spec: Any, *, name: str, baudrate: int = 9600, timeout: float = 0.25,
                 terminator: bytes = b"\r\n", line_ending: bytes = b"\r\n", reconnect_interval: float = 0.5,
                 max_line: int = 512, list_ports: Callable[[], list] | None = None,
                 on_reconnect: Callable[[], None] | None = None, clock: Callable[[], float] = time.monotonic,
                 open_now: bool = True) -> None:
        if not (isinstance(spec, (str, serial.SerialBase)) or callable(spec)):
            raise TypeError(f"spec must be a port name/URL, 'usb-serial:<sn>', a callable or a serial.SerialBase; "
                            f"got {type(spec).__name__}")
        if timeout <= 0:
            raise ValueError(f"timeout must be > 0 s; got {timeout}")
        self.spec = spec
        self.name = name
        self.baudrate = int(baudrate)
        self.timeout = float(timeout)
        self.terminator = terminator
        self.line_ending = line_ending
        self.reconnect_interval = float(reconnect_interval)
        self.max_line = int(max_line)
        # reads block at most this long per call, so the deadline is kept without reconfiguring the port
        self._slice = min(0.01, self.timeout)
        self.list_ports = list_ports
        self.on_reconnect = on_reconnect
        self.clock = clock
        self.lock = threading.RLock()
        self.port: serial.SerialBase | None = None
        self.device: str | None = None  # the resolved device name/URL of the current connection
        self.n_connects = 0
        self._last_attempt = -float("inf")
        if open_now:
            self.open()

    # -- connection -------------------------------------------------------------------------------
    def resolve(self) -> str:
        """Resolve the spec to a device name/URL now (may raise :class:`Disconnected`)."""
        spec = self.spec
        if callable(spec) and not isinstance(spec, serial.SerialBase):
            spec = spec()
            if spec is None:
                raise Disconnected(f"{self.name}: the port resolver found no device")
        if not isinstance(spec, str):
            raise TypeError(f"{self.name}: port resolver must return a str; got {type(spec).__name__}")
        if spec.startswith(USB_SERIAL_PREFIX):
            return find_port_by_serial(spec[len(USB_SERIAL_PREFIX):], self.list_ports)
        return spec

    def open(self) -> None:
        """Open (or re-open) the port; raises :class:`Disconnected` if it cannot be opened."""
        with self.lock:
            self._last_attempt = self.clock()
            self._close_quietly()
            try:
                if isinstance(self.spec, serial.SerialBase):
                    port = self.spec
                    if not port.is_open:
                        port.open()
                    port.timeout = self._slice
                    device = str(port.port)
                else:
                    device = self.resolve()
                    port = serial.serial_for_url(device, baudrate=self.baudrate, timeout=self._slice,
                                                 write_timeout=max(1.0, self.timeout))
            except Disconnected:
                raise
            except _PORT_ERRORS as exc:
                raise Disconnected(f"{self.name}: cannot open port {self.spec!r}: {exc}") from exc
            self.port, self.device = port, device
            self.n_connects += 1
            log.info("%s: opened %s", self.name, device)
            if self.n_connects > 1 and self.on_reconnect is not None:
                self.on_reconnect()

    def close(self) -> None:
        """Close the port (idempotent)."""
        with self.lock:
            self._close_quietly()

    def _close_quietly(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            # pyserial's socket:// close() skips closing the socket when shutdown() fails on a dead
            # connection; close it ourselves so nothing leaks
            sock = getattr(port, "_socket", None)
            try:
                port.close()
            except _PORT_ERRORS:  # pragma: no cover - closing a dead port
                pass
            if sock is not None:
                try:
                    sock.close()
                except OSError:  # pragma: no cover
                    pass

    @property
    def is_open(self) -> bool:
        return self.port is not None

    def ensure_open(self) -> serial.SerialBase:
        """Return the open port, re-opening a vanished one at most every ``reconnect_interval`` s."""
        if self.port is not None:
            return self.port
        if self.clock() - self._last_attempt < self.reconnect_interval:
            raise Disconnected(f"{self.name}: port {self.spec!r} is disconnected (retrying every "
                               f"{self.reconnect_interval} s)")
        self.open()
        assert self.port is not None
        return self.port

    def _lost(self, exc: BaseException, during: str) -> Disconnected:
        self._close_quietly()
        self._last_attempt = self.clock()
        log.warning("%s: port lost during %s: %s", self.name, during, exc)
        return Disconnected(f"{self.name}: port {self.device!r} lost during {during}: {exc}")

    # -- I/O --------------------------------------------------------------------------------------
    def send(self, command: bytes, *, flush_input: bool = True) -> None:
        """Send one command (``line_ending`` must already be part of ``command``) after flushing stale input."""
        with self.lock:
            port = self.ensure_open()
            try:
                if flush_input:
                    port.reset_input_buffer()
                port.write(command)
                port.flush()
            except _PORT_ERRORS as exc:
                raise self._lost(exc, f"write of {command!r}") from exc

    def read_line(self, timeout: float | None = None) -> bytes:
        """Read one reply line including its terminator.

        Raises
        ------
        InstrumentTimeout
            Nothing, or only part of a line, arrived within ``timeout`` (default ``self.timeout``).
        GarbledReply
            More than ``max_line`` bytes without a terminator.
        Disconnected
            The port vanished.
        """
        with self.lock:
            port = self.ensure_open()
            timeout = self.timeout if timeout is None else timeout
            deadline = self.clock() + timeout
            buf = bytearray()
            term = self.terminator
            try:
                while True:
                    remaining = deadline - self.clock()
                    if remaining <= 0:
                        break
                    n = max(1, port.in_waiting)
                    chunk = port.read(n)
                    if chunk:
                        buf += chunk
                        idx = buf.find(term)
                        if idx >= 0:
                            line = bytes(buf[: idx + len(term)])
                            rest = bytes(buf[idx + len(term):])
                            if rest:
                                log.debug("%s: discarding bytes after the reply: %r", self.name, rest)
                            return line
                        if len(buf) > self.max_line:
                            raise GarbledReply(f"{self.name}: {len(buf)} bytes without terminator {term!r}",
                                               raw=bytes(buf))
            except InstrumentError:
                raise
            except _PORT_ERRORS as exc:
                raise self._lost(exc, "read") from exc
            if buf:
                raise InstrumentTimeout(f"{self.name}: partial reply {bytes(buf)!r} without terminator "
                                        f"after {timeout:.3g} s", raw=bytes(buf))
            raise InstrumentTimeout(f"{self.name}: no reply within {timeout:.3g} s", raw=b"")

    def query(self, command: bytes, timeout: float | None = None) -> bytes:
        """Flush stale input, send ``command`` and read one reply line."""
        with self.lock:
            self.send(command)
            return self.read_line(timeout)

    def collect_lines(self, window: float) -> list[bytes]:
        """Read whatever complete lines arrive within ``window`` s (a tolerant read; may be empty).

        Used after set commands whose acknowledgement the manual does not promise: nothing is waited for
        beyond ``window``; incomplete trailing bytes are discarded.
        """
        with self.lock:
            port = self.ensure_open()
            deadline = self.clock() + window
            buf = bytearray()
            try:
                while self.clock() < deadline:
                    n = port.in_waiting
                    if n:
                        buf += port.read(n)
                    else:
                        time.sleep(0.002)
            except _PORT_ERRORS as exc:
                raise self._lost(exc, "read") from exc
            parts = bytes(buf).split(self.terminator)
            return [p + self.terminator for p in parts[:-1]]

    def pause(self, seconds: float) -> None:
        """Let a late reply arrive, then discard it (used between retries)."""
        time.sleep(seconds)
        with self.lock:
            if self.port is not None:
                try:
                    self.port.reset_input_buffer()
                except _PORT_ERRORS as exc:
                    raise self._lost(exc, "flush") from exc
