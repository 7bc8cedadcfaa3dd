"""What a stage raises: bad input (exit code 2) or a failed operation (exit code 1), decision 0007.

The command line prints either as its one-line error; a Python caller catches them as
``acquisition.errors.InputError`` / ``OperationError`` (or these subclasses).
"""

from __future__ import annotations

from acquisition.errors import InputError, OperationError

__all__ = ["StageError", "StageFailed", "StageUnavailable"]


class StageError(InputError):
    """A stage could not run on a session's contents or its settings (missing or unusable input): exit code 2."""


class StageUnavailable(StageError):
    """The stage's implementation is not installed in this build."""


class StageFailed(OperationError):
    """The input was usable but the stage failed (no convergence, ill-posed result, a file not written): exit code 1."""
