"""Why a run stops: the runner's exceptions."""

from __future__ import annotations


class RunnerError(RuntimeError):
    """The runner cannot continue (safety limit, repeated capture failure...)."""


class SessionAborted(RunnerError):
    """The session was aborted (by the operator or a safety limit); the runner's status is 'aborted'.

    ``resumable``: the completed steps are sound and the cause can be fixed (a safety limit that
    tripped, a capture that kept failing): the file stays resumable. An operator's abort is final.
    """

    def __init__(self, message: str, *, resumable: bool = False):
        super().__init__(message)
        self.resumable = resumable


class DiskFull(RunnerError):
    """Not enough free space for the next write: stopped at a step boundary, resumable."""


class SessionQuit(RunnerError):
    """The operator stopped the session to resume it later; status stays resumable ('interrupted')."""
