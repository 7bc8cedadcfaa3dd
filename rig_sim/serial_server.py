"""Serve a simulated device on a pseudo-terminal or a loopback TCP socket, with fault injection.

Pseudo-terminal: ``pty.openpty()`` in raw mode; the driver opens the real ``/dev/pts/N`` with pyserial.
A pty path cannot be re-used after the master is closed, so "unplug/replug" works like udev does for USB
adapters: the server keeps a *stable symlink* (``<dir>/by-id/<name>``, like ``/dev/serial/by-id``) to the
current ``/dev/pts/N``. ``unplug()`` closes the pty (the driver's reads fail with EIO) and removes the
link; ``replug()`` opens a new pty and re-points the link, so a driver that opened the link path finds
the device again. ``list_ports()``-style lookup by serial number is offered by ``SimulatedRig``.

Socket: ``socket://127.0.0.1:PORT``; unplug closes the connection and the listener (connection refused),
replug listens again on the same port.

All I/O happens on the server thread; control calls (unplug/replug) are queued to it and wait for it.
"""

from __future__ import annotations

import logging
import os
import pty
import queue
import re
import selectors
import socket
import threading
import time
import tty
from typing import Callable

import numpy as np

log = logging.getLogger(__name__)

Handler = Callable[[str], "bytes | None"]


class FaultInjector:
    """Faults applied by a :class:`DeviceServer` to its next replies.

    Counters count *replies* (commands that get no reply are not affected).
    """

    def __init__(self, server: "DeviceServer", inject_device_error: Callable[[int], None]) -> None:
        self._server = server
        self._inject_device_error = inject_device_error
        self.lock = threading.Lock()
        self.n_garble = 0
        self.n_truncate = 0
        self.n_silence = 0
        self.delay_s = 0.0

    def garble(self, n: int = 1) -> None:
        """Replace the next ``n`` replies by random non-ASCII bytes (terminated)."""
        with self.lock:
            self.n_garble += n

    def truncate(self, n: int = 1) -> None:
        """Send only the first half of the next ``n`` replies, without terminator."""
        with self.lock:
            self.n_truncate += n

    def silence(self, n: int = 1) -> None:
        """Do not answer the next ``n`` queries."""
        with self.lock:
            self.n_silence += n

    def device_error(self, n: int = 1) -> None:
        """Make the device report an error (Mensor: error-queue entry, ``E`` flag; Mark-10: ``*10``)."""
        self._inject_device_error(n)

    def slow(self, delay_s: float) -> None:
        """Delay every reply by ``delay_s`` (0 restores normal speed)."""
        with self.lock:
            self.delay_s = max(0.0, float(delay_s))

    def unplug(self) -> None:
        """Pull the cable: the port disappears."""
        self._server.unplug()

    def replug(self) -> None:
        """Plug it back: the port reappears (same stable path or URL)."""
        self._server.replug()

    def clear(self) -> None:
        """Remove all pending faults and delays."""
        with self.lock:
            self.n_garble = self.n_truncate = self.n_silence = 0
            self.delay_s = 0.0

    def apply(self, reply: bytes, rng: np.random.Generator) -> tuple[bytes | None, float]:
        """Return the bytes to send (None: nothing) and the delay before sending."""
        with self.lock:
            delay = self.delay_s
            if self.n_silence:
                self.n_silence -= 1
                return None, delay
            if self.n_garble:
                self.n_garble -= 1
                return bytes(rng.integers(0x80, 0x100, size=8, dtype=np.uint8)) + b"\r\n", delay
            if self.n_truncate:
                self.n_truncate -= 1
                return reply[: max(1, (len(reply) - 2) // 2)], delay
            return reply, delay


class DeviceServer:
    """Serve ``handler`` (one command line in, reply bytes or None out) on a pty or a loopback socket.

    Parameters
    ----------
    handler : callable
        ``handler(line: str) -> bytes | None``.
    transport : {"pty", "socket"}
    link_path : str, optional
        For pty: the stable symlink to maintain (its directory must exist).
    rng : numpy.random.Generator
        For garbage bytes.
    inject_device_error : callable
        ``f(n)`` asking the device model to report ``n`` errors.
    """

    def __init__(self, handler: Handler, *, transport: str = "pty", link_path: str | None = None,
                 rng: np.random.Generator | None = None,
                 inject_device_error: Callable[[int], None] | None = None, name: str = "device") -> None:
        if transport not in ("pty", "socket"):
            raise ValueError(f"transport must be 'pty' or 'socket'; got {transport!r}")
        self.handler = handler
        self.transport = transport
        self.link_path = link_path
        self.rng = rng if rng is not None else np.random.default_rng(2)
        self.name = name
        self.faults = FaultInjector(self, inject_device_error or (lambda n: None))
        self.plugged = False
        self.device_path: str | None = None  # current /dev/pts/N or socket URL
        self.n_requests = 0
        self._master: int | None = None
        self._slave: int | None = None
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._port_number: int = 0
        self._buf = b""
        self._control: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name=f"sim-{name}", daemon=True)

    # -- public ------------------------------------------------------------------------------------
    @property
    def port(self) -> str:
        """What a driver should open: the stable symlink (pty) or ``socket://127.0.0.1:PORT``."""
        if self.transport == "socket":
            return f"socket://127.0.0.1:{self._port_number}"
        return self.link_path or str(self.device_path)

    def start(self) -> "DeviceServer":
        self._plug()
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        os.write(self._wake_w, b"x")
        self._thread.join(5.0)
        self._unplug()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def unplug(self) -> None:
        self._call(self._unplug)

    def replug(self) -> None:
        self._call(self._plug)

    def _call(self, fn: Callable[[], None]) -> None:
        if not self._thread.is_alive():
            fn()
            return
        done = threading.Event()
        self._control.put((fn, done))
        os.write(self._wake_w, b"x")
        if not done.wait(5.0):  # pragma: no cover
            raise RuntimeError(f"{self.name}: server thread did not process the control request")

    # -- plug / unplug (server thread) ---------------------------------------------------------------
    def _plug(self) -> None:
        if self.plugged:
            return
        self._buf = b""
        if self.transport == "pty":
            master, slave = pty.openpty()
            tty.setraw(slave)
            tty.setraw(master)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.device_path = os.ttyname(slave)
            if self.link_path:
                tmp = f"{self.link_path}.tmp{os.getpid()}"
                if os.path.lexists(tmp):
                    os.unlink(tmp)
                os.symlink(self.device_path, tmp)
                os.replace(tmp, self.link_path)
        else:
            lst = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            lst.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            lst.bind(("127.0.0.1", self._port_number))
            lst.listen(1)
            lst.setblocking(False)
            self._listener = lst
            self._port_number = lst.getsockname()[1]
            self.device_path = self.port
        self.plugged = True
        log.info("%s: plugged at %s", self.name, self.device_path)

    def _unplug(self) -> None:
        if not self.plugged:
            return
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        for s in (self._conn, self._listener):
            if s is not None:
                try:
                    s.close()
                except OSError:
                    pass
        self._conn = self._listener = None
        if self.link_path and os.path.lexists(self.link_path):
            os.unlink(self.link_path)
        self.plugged = False
        log.info("%s: unplugged", self.name)

    # -- serving -------------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            sel = selectors.DefaultSelector()
            try:
                sel.register(self._wake_r, selectors.EVENT_READ, "wake")
                if self._master is not None:
                    sel.register(self._master, selectors.EVENT_READ, "pty")
                if self._conn is not None:
                    sel.register(self._conn, selectors.EVENT_READ, "conn")
                elif self._listener is not None:
                    sel.register(self._listener, selectors.EVENT_READ, "listen")
                events = sel.select(0.2)
            finally:
                sel.close()
            for key, _ in events:
                if key.data == "wake":
                    os.read(self._wake_r, 4096)
                    while not self._control.empty():
                        fn, done = self._control.get()
                        try:
                            fn()
                        finally:
                            done.set()
                elif key.data == "listen" and self._listener is not None:
                    try:
                        conn, _ = self._listener.accept()
                    except OSError:
                        continue
                    conn.setblocking(False)
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self._conn, self._buf = conn, b""
                elif key.data == "pty" and self._master is not None:
                    try:
                        data = os.read(self._master, 4096)
                    except BlockingIOError:
                        continue
                    except OSError:  # no slave open at the moment (EIO): wait for the driver
                        time.sleep(0.01)
                        continue
                    self._feed(data)
                elif key.data == "conn" and self._conn is not None:
                    try:
                        data = self._conn.recv(4096)
                    except BlockingIOError:
                        continue
                    except OSError:
                        data = b""
                    if not data:  # client went away; accept the next one
                        self._conn.close()
                        self._conn = None
                        continue
                    self._feed(data)

    def _feed(self, data: bytes) -> None:
        self._buf += data
        parts = re.split(rb"[\r\n]", self._buf)
        self._buf = parts[-1]
        if len(self._buf) > 4096:
            self._buf = b""
        for raw in parts[:-1]:
            if not raw:
                continue
            line = raw.decode("ascii", "replace")
            self.n_requests += 1
            reply = self.handler(line)
            if reply is None:
                continue
            out, delay = self.faults.apply(reply, self.rng)
            if delay > 0 and self._stop.wait(delay):
                return
            if out:
                self._write(out)

    def _write(self, data: bytes) -> None:
        try:
            if self._master is not None:
                view = memoryview(data)
                while view:
                    try:
                        n = os.write(self._master, view)
                    except BlockingIOError:
                        time.sleep(0.001)
                        continue
                    view = view[n:]
            elif self._conn is not None:
                self._conn.sendall(data)
        except OSError as exc:
            log.debug("%s: write failed: %s", self.name, exc)
