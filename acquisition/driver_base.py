"""What the two instrument drivers share: the reading record and the bounded-retry query loop."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable, TypeVar

from acquisition.instrument_errors import GarbledReply, InstrumentTimeout
from acquisition.serial_link import SerialLink

log = logging.getLogger(__name__)
T = TypeVar("T")


@dataclass(frozen=True)
class Reading:
    """One reading of an instrument.

    Attributes
    ----------
    value : float
        The reading in SI units (Pa for pressure, N for force).
    raw : str
        The reply exactly as received (terminator stripped), for the session log.
    unit : str
        The device unit the raw reply is expressed in (e.g. ``"mmHg"``, ``"lbF"``).
    """

    value: float
    raw: str
    unit: str


class RetryingDriver:
    """Base of the drivers: a :class:`SerialLink` plus a bounded retry of timeouts and garbled replies.

    Device errors and disconnections are never retried here: a device error is an answer, and a
    disconnection is handled by the link (re-open on a later call) and by the caller (pause/resume).
    """

    def __init__(self, link: SerialLink, *, retries: int = 2, retry_pause: float = 0.02) -> None:
        if retries < 0:
            raise ValueError(f"retries must be >= 0; got {retries}")
        self.link = link
        self.retries = int(retries)
        self.retry_pause = float(retry_pause)
        self.n_retries = 0  # total retries so far (diagnostics)
        self._stale = False  # True after a reconnect: settings are re-read before the next command
        link.on_reconnect = self._mark_stale

    def _mark_stale(self) -> None:
        self._stale = True

    def _refresh(self) -> None:
        """Read identity and settings from the device (drivers implement it)."""
        raise NotImplementedError

    def _ensure(self) -> None:
        """Open the port if needed and, after a reconnect, re-read the device's settings first
        (a replugged adapter may front a reconfigured or different device)."""
        self.link.ensure_open()
        if self._stale:
            self._stale = False
            try:
                self._refresh()
            except BaseException:
                self._stale = True
                raise

    @property
    def name(self) -> str:
        return self.link.name

    def _query(self, command: bytes, parse: Callable[[bytes], T]) -> T:
        """Send ``command``, parse the reply line; retry timeouts and garbled replies ``retries`` times."""
        with self.link.lock:
            attempt = 0
            while True:
                try:
                    return parse(self.link.query(command))
                except (InstrumentTimeout, GarbledReply) as exc:
                    if attempt >= self.retries:
                        raise
                    attempt += 1
                    self.n_retries += 1
                    log.info("%s: %s; retry %d/%d of %r", self.name, exc, attempt, self.retries, command)
                    # let a late reply to the failed attempt arrive, then flush it so it is not taken
                    # for the answer to the retry
                    self.link.pause(self.retry_pause)

    def close(self) -> None:
        """Close the port."""
        self.link.close()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def decode_reply_line(raw: bytes, device: str) -> str:
    """One ASCII reply line without its CR LF, as both the Mensor and the Mark-10 send them.

    Raises TypeError if ``raw`` is not bytes, GarbledReply if it is not ASCII, empty, or holds
    control characters (line noise or a wrong baud rate).
    """
    if not isinstance(raw, (bytes, bytearray)):
        raise TypeError(f"raw must be bytes; got {type(raw).__name__}")
    body = bytes(raw)
    if body.endswith(b"\r\n"):
        body = body[:-2]
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError as exc:
        raise GarbledReply(f"{device} reply is not ASCII: {bytes(raw)!r}", raw=bytes(raw)) from exc
    if not text or any(ord(c) < 32 or ord(c) == 127 for c in text):
        raise GarbledReply(f"{device} reply empty or with control characters: {bytes(raw)!r}", raw=bytes(raw))
    return text
