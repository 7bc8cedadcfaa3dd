"""The two kinds of failure every reader and command reports, and their exit codes.

``InputError``      the input is bad: a file that is malformed, damaged, foreign or physically
                    implausible, or an option out of range. The user fixes the input. Exit code 2.
``OperationError``  the input was fine but the operation failed: a device fault, a file that
                    cannot be written, a computation that did not converge. Exit code 1.

Library code raises subclasses of these (``CsvFormatError``, ``SessionError``, ...) with one
sentence naming the file, the place in it (line, column, HDF5 path), what was expected and what
was found. Only the CLI entry (``vfmlab.cli.main``) turns them into exit codes, in one table;
decision 0007 lists the codes and the validation rules.
"""

from __future__ import annotations

__all__ = ["InputError", "DamagedFileError", "ImplausibleInputError", "OperationError", "EXIT_OK",
           "EXIT_FAILED", "EXIT_BAD_INPUT", "EXIT_INTERRUPTED"]

# Also spelled out in vfmlab/cli/__init__.py (which avoids importing acquisition for --help).
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class InputError(ValueError):
    """Bad input: malformed, damaged, foreign or implausible; the message says what and where. Exit code 2."""


class DamagedFileError(InputError):
    """A file opens but part of it cannot be read (bit flips, truncation, a foreign writer)."""


class ImplausibleInputError(InputError):
    """Well-formed input whose values are physically implausible for this rig and specimen."""


class OperationError(RuntimeError):
    """The input was fine but the operation failed (device, file system, computation). Exit code 1."""
