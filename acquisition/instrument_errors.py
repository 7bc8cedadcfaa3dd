"""Typed instrument faults, so a session runner can decide to retry, pause or abort.

``InstrumentError`` is the base; every driver call raises only its subclasses.
"""

from __future__ import annotations


class InstrumentError(Exception):
    """Base class of all instrument faults.

    Parameters
    ----------
    message : str
        What happened, naming the instrument and the command.
    raw : bytes or str, optional
        The raw bytes received (possibly partial), kept for the log.
    """

    def __init__(self, message: str, raw: bytes | str | None = None) -> None:
        super().__init__(message)
        self.raw = raw


class InstrumentTimeout(InstrumentError):
    """No complete, terminated reply arrived in time (a partial reply counts as a timeout)."""


class GarbledReply(InstrumentError):
    """A terminated reply arrived but does not parse as the expected answer."""


class DeviceError(InstrumentError):
    """The device reported an error (Mensor ``E`` flag with its error queue, Mark-10 ``*NN``).

    Attributes
    ----------
    code : str or None
        Device error code, e.g. ``"*10"`` for the Mark-10.
    messages : list of str
        Entries read from the device's error queue (Mensor), oldest first.
    value : float or None
        The value carried by the flagged reply, in SI units, if it parsed.
    """

    def __init__(self, message: str, raw: bytes | str | None = None, *, code: str | None = None,
                 messages: list[str] | None = None, value: float | None = None) -> None:
        super().__init__(message, raw)
        self.code = code
        self.messages = list(messages or [])
        self.value = value


class Disconnected(InstrumentError):
    """The port disappeared (cable pulled, adapter re-enumerated) or cannot be opened."""
