"""What a session file holds: the schema version, tables, dtypes, record types, errors and the validator.

The layout itself is described in the package docstring (:mod:`acquisition.session`) and in
``docs/guide/session-format.md``.
"""

from __future__ import annotations

import datetime as _dt
import functools
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.errors import DamagedFileError, InputError, OperationError

SCHEMA_VERSION = "1.0"
_REQUIRED_GROUPS = ("entry", "entry/sample", "entry/instrument", "entry/protocol", "entry/log", "entry/steps")
_STEP_COLUMNS: dict[str, tuple[str, str]] = {
    # name: (dtype, units)
    "block": ("i4", ""),
    "stretch": ("f8", "1"),
    "target_pressure": ("f8", "Pa"),
    "pressure": ("f8", "Pa"),
    "force": ("f8", "N"),
    "t_monotonic": ("f8", "s"),
    "t_wall": ("f8", "s"),
    "supersedes": ("i4", ""),
}
_LOG_CHANNELS = {"pressure": "Pa", "force": "N"}
_RAW_DTYPE = "S48"  # fixed length: SWMR cannot grow variable-length data safely
_EVENT_KIND_DTYPE = "S32"
_EVENT_MESSAGE_DTYPE = "S512"
_STATUS_DTYPE = "S16"
_LOG_CHUNK = 4096
_STATUSES = ("running", "complete", "aborted", "interrupted")


class SessionError(InputError):
    """A session file is missing, unreadable, of another schema, or lacks something required (exit code 2)."""


class DamagedSessionError(SessionError, DamagedFileError):
    """The session file opens but a group, dataset or attribute cannot be read (bit flips, truncation)."""


class SessionWriteError(SessionError, OperationError):
    """A session file could not be written (read-only medium, disk full, locked): a failed operation, exit code 1."""


@dataclass(frozen=True)
class SpecimenInfo:
    """The specimen's identity and reference geometry (SI: metres)."""

    specimen_id: str
    radius: float
    length: float
    thickness: float
    notes: str = ""
    #: How the specimen is held: "clamped" (tied on cannulae), "free", or "" when nobody said.
    ends: str = ""
    #: Where ``ends`` comes from (e.g. "specimen file", "rig file", "simulated specimen", "import option").
    ends_source: str = ""

    def __post_init__(self) -> None:
        if self.ends not in ("", "clamped", "free"):
            raise ValueError(f"SpecimenInfo.ends must be 'clamped', 'free' or '' (unknown); got {self.ends!r}")
        for name in ("radius", "length", "thickness"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f"SpecimenInfo.{name} must be a positive length in metres; got {value!r}")
            if value > 1.0:
                raise ValueError(
                    f"SpecimenInfo.{name} must be in metres (an artery is < 1 m); got {value!r} — mm given?"
                )


@dataclass(frozen=True)
class CameraSpec:
    """A camera as the session file records it (its frames are ``(height, width)`` of ``dtype``)."""

    name: str
    model: str
    width: int
    height: int
    dtype: str = "uint8"


@dataclass(frozen=True)
class StepRecord:
    """One captured step: targets and readings (Pa, N, s). ``supersedes`` is the row it retakes, or -1."""

    block: int
    stretch: float
    target_pressure: float
    pressure: float
    force: float
    t_monotonic: float
    t_wall: float
    supersedes: int = -1


def _now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


@functools.cache
def _software_version() -> str:
    """The installed vfmlab version (what sessions and results record), as ``vfmlab.__version__`` gives it.

    Read here rather than imported from :mod:`vfmlab`: the stage package does not import the layer above it.
    Cached (as ``vfmlab.__version__`` is): the installed version does not change while the process runs,
    and importlib.metadata takes milliseconds per look-up.
    """
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vfmlab")
    except PackageNotFoundError:  # running from a source tree without installation
        return "0.1.0+source"


def _fixed(text: str, dtype: str) -> bytes:
    size = int(dtype[1:])
    data = str(text).encode("utf-8", "replace")
    if len(data) > size:
        data = data[: size - 3] + b"..."
    return data


def _decode(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.dtype.kind in "SO":
        return np.array([v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v) for v in value.ravel()],
                        dtype=object).reshape(value.shape).astype(str)
    return value


def _read(ds: h5py.Dataset) -> Any:
    return _decode(ds[()])


def _check_result_arrays(kind: str, arrays: Mapping[str, Any]) -> None:
    """Shapes the readers of a result rely on; ValueError (reported as damage) when they do not hold."""
    if kind == "markers":
        if "positions" not in arrays:
            raise ValueError("a markers result must hold 'positions'; it has " + str(sorted(arrays)))
        pos = np.asarray(arrays["positions"])
        if pos.ndim != 3 or pos.shape[2] != 3 or pos.dtype.kind not in "fiu":
            raise ValueError(f"positions must be numbers of shape (n_steps, n_markers, 3); found {pos.dtype.name} "
                             f"of shape {pos.shape}")
        for key, shape in (("visible", pos.shape[:2]), ("step_index", pos.shape[:1]), ("step_number", pos.shape[:1]),
                           ("marker_id", pos.shape[1:2]), ("marker_label", pos.shape[1:2])):
            if key in arrays and np.shape(arrays[key]) != shape:
                raise ValueError(f"{key} must have shape {shape} to match positions; found {np.shape(arrays[key])}")
    elif kind == "identification" and "parameters" in arrays:
        values, names = np.asarray(arrays["parameters"]), np.asarray(arrays.get("parameter_names", []))
        if values.ndim != 1 or values.dtype.kind not in "fiu" or ("parameter_names" in arrays
                                                                  and names.shape != values.shape):
            raise ValueError(f"parameters must be numbers of shape (n_parameters,) matching parameter_names; found "
                             f"{values.dtype.name} of shape {values.shape} for {names.size} names")


def _validate(f: h5py.File, path: Path) -> None:
    version = f.attrs.get("vfmlab_schema_version")
    if version is None:
        raise SessionError(f"{path}: not a vfmlab session (no 'vfmlab_schema_version' attribute on the root group)")
    version = _decode(version)
    if not isinstance(version, str):
        raise SessionError(f"{path}: the schema version (/@vfmlab_schema_version) must be a string like "
                           f"{SCHEMA_VERSION!r}; found {type(version).__name__} {version} (not written by vfmlab?)")
    try:
        major, _minor = (int(part) for part in version.split("."))
    except ValueError:
        raise SessionError(f"{path}: the schema version (/@vfmlab_schema_version) must look like "
                           f"{SCHEMA_VERSION!r}; found {version!r}") from None
    supported = int(SCHEMA_VERSION.split(".")[0])
    if major > supported:
        raise SessionError(
            f"{path}: schema version {version} is newer than this vfmlab supports ({SCHEMA_VERSION}); upgrade vfmlab"
        )
    if major < supported:
        raise SessionError(
            f"{path}: schema version {version} is older than this vfmlab supports ({SCHEMA_VERSION}); "
            "convert it with the vfmlab version that wrote it"
        )
    for group in _REQUIRED_GROUPS:
        if group not in f:
            raise SessionError(f"{path}: missing required group '/{group}'")
    for column in _STEP_COLUMNS:
        if column not in f["entry/steps"]:
            raise SessionError(f"{path}: missing required dataset '/entry/steps/{column}'")
    for key in ("name", "radius", "length", "thickness"):
        if key not in f["entry/sample"]:
            raise SessionError(f"{path}: missing required dataset '/entry/sample/{key}'")
