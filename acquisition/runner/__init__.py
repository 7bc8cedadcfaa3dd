"""The session runner: executes a :class:`~acquisition.protocol.Protocol` on the rig, step by step.

A small executor in the spirit of bluesky plans with ``finalize_wrapper``: whatever happens
(completion, operator abort, instrument fault, exception, Ctrl-C) the clean-up runs: the
pressure controller is vented (or the operator told to release the pressure), the cameras are
closed and the session file gets its status.

Sequence: preconditioning (logged, imaged only if the protocol asks), then for each block
(axial stretch) and each pressure level: set the stretch (stage or operator), set the
pressure (controller ``Setpt`` or operator), wait until the pressure is stable (band + dwell,
from the sampler), capture every camera and the instrument readings together, write the step
(flushed + fsynced). The continuous instrument log is drained from the sampler into the
session file as it happens (every ``tick_s``).

Pausing: :meth:`SessionRunner.request_pause` (the CLI calls it on Ctrl-C) pauses at the next
safe point (never inside a capture or a file write) and asks the operator to resume, retake the
last step, quit (leave the session resumable) or abort. An instrument fault (timeout,
disconnect, device error) pauses the session with a message and resumes by itself when the
instrument is back.

Collaborators are duck-typed so the runner stays independent of the concrete drivers:

- ``pressure``: ``identity``, ``is_controller``, ``set_mode(str)``, ``set_setpoint(Pa)``
- ``sampler``: ``latest(ch)``, ``drain(ch)``, ``drain_events()``, ``status(ch)``, ``healthy``,
  ``is_stable(band, dwell, target)``, ``history(ch, seconds)``
  (``acquisition.instruments.Sampler``)
- ``writer``: :class:`acquisition.session.SessionWriter`
- ``cameras``: :class:`acquisition.cameras.Camera` objects (open)
- ``operator``: :class:`Operator`
"""

from __future__ import annotations

from acquisition.runner._errors import DiskFull, RunnerError, SessionAborted, SessionQuit
from acquisition.runner._operator import AutoOperator, Choice, Operator
from acquisition.runner._runner import SessionRunner
from acquisition.runner._safety import CHANNELS
from acquisition.runner._state import RunnerState, completed_steps

__all__ = [
    "RunnerError",
    "SessionAborted",
    "SessionQuit",
    "DiskFull",
    "Operator",
    "AutoOperator",
    "RunnerState",
    "SessionRunner",
    "completed_steps",
    "Choice",
    "CHANNELS",
]
