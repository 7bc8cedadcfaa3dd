"""The HDF5 session file: one file per test, the contract between the stages.

Layout (NeXus-like, documented in ``docs/guide/session-format.md``)::

    /                       @vfmlab_schema_version, @creator, @HDF5_Version, @h5py_version, @file_time
    /entry                  NXentry  @start_time @software_version @writer_pid @writer_host
        status              "running" | "complete" | "aborted"   (readers report "interrupted"
                            when the writer that said "running" is gone)
        end_time
        sample/             NXsample: name, radius, length, thickness (m), notes, ends ("clamped" |
                            "free", absent when unknown; @source says who said so)
        instrument/         NXinstrument: pressure/, load_cell/ (identity, settings JSON,
                            load_cell@measures), cameras/<name>/ (model, width, height),
                            rig_settings (JSON)
        protocol/           NXnote: data (text as run), @sha256
        log/pressure, log/force   NXlog: time (POSIX s), monotonic_time (s), value (Pa | N),
                            raw (reply bytes), seq
        steps/              NXdata: one row per captured step (block, stretch, target_pressure,
                            pressure, force, t_monotonic, t_wall, supersedes), images/<camera>
                            (n_steps, H, W), one frame per gzip-1 chunk
        calibration/images/<camera>   (n_views, H, W) board images
        events/             time, kind, message
        results/<kind>_NNN  NXprocess: derived results, never overwritten

Crash safety: the writer pre-creates every growing dataset, then switches to SWMR mode, and
flushes + fsyncs after every step, so a process killed at any point leaves a file that opens
(``swmr=True``) and holds every completed step. Readers may open it while it is being written.
"""

from __future__ import annotations

import atexit
import contextlib
import datetime as _dt
import errno
import fcntl
import functools
import re
import shutil
import hashlib
import json
import logging
import os
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.errors import DamagedFileError, InputError, OperationError
from acquisition.h5journal import JournalError, LockTimeout, journaled_h5, lock_timeout, recover, wait_lock
from acquisition.h5recover import clear_consistency_flags

__all__ = [
    "SCHEMA_VERSION",
    "SessionError",
    "DamagedSessionError",
    "SessionWriteError",
    "SpecimenInfo",
    "CameraSpec",
    "StepRecord",
    "SessionWriter",
    "Session",
    "open_session",
    "start_preflight",
    "write_result",
    "incomplete_leftover",
]

log = logging.getLogger(__name__)

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


def _create_h5(tmp: Path, path: Path) -> h5py.File:
    """A new HDF5 file at ``tmp``; a failure names ``path`` (what the user asked for), not the temporary name."""
    try:
        return h5py.File(tmp, "w", libver="latest")
    except OSError as exc:
        found = re.search(r"errno = (\d+)", str(exc))
        code = int(found.group(1)) if found else (exc.errno or errno.EIO)
        raise OSError(code, f"cannot create the file: {os.strerror(code)}", str(path)) from None


def _now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def _software_version() -> str:
    from vfmlab import __version__

    return __version__


def _fixed(text: str, dtype: str) -> bytes:
    size = int(dtype[1:])
    data = str(text).encode("utf-8", "replace")
    if len(data) > size:
        data = data[: size - 3] + b"..."
    return data


def _growable(group: h5py.Group, name: str, dtype: Any, units: str | None, chunk: int = _LOG_CHUNK) -> h5py.Dataset:
    ds = group.create_dataset(name, shape=(0,), maxshape=(None,), chunks=(chunk,), dtype=dtype)
    if units is not None:
        ds.attrs["units"] = units
    return ds


def _append(ds: h5py.Dataset, values: np.ndarray) -> None:
    n = ds.shape[0]
    ds.resize((n + len(values),) + ds.shape[1:])
    ds[n:] = values


class SessionWriter:
    """The one writer of a session file. Use :meth:`create` or :meth:`resume`, as a context manager.

    Leaving the ``with`` block normally marks the session "complete"; leaving it through an
    exception marks it "aborted" (Ctrl-C included). A killed process leaves "running", which
    readers report as "interrupted" and :meth:`resume` continues.
    """

    def __init__(self, h5file: h5py.File, path: Path):
        self._f = h5file
        self.path = path
        self._entry = h5file["entry"]
        self._closed = False

    # -- construction -------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        path: str | os.PathLike,
        specimen: SpecimenInfo,
        *,
        cameras: Sequence[CameraSpec] = (),
        protocol_text: str = "",
        rig: Mapping[str, Any] | None = None,
        instruments: Mapping[str, Mapping[str, Any]] | None = None,
        load_cell_measures: str = "wall",
        overwrite: bool = False,
    ) -> SessionWriter:
        """Create a new session file and open it for crash-safe appending.

        Parameters
        ----------
        path : path of the new file; refused if it exists unless ``overwrite``.
        specimen : identity and reference geometry.
        cameras : the cameras whose frames each step stores.
        protocol_text : the protocol file as run (stored verbatim with its SHA-256).
        rig : JSON-serialisable snapshot of the rig configuration.
        instruments : ``{"pressure": {"identity": str, "settings": {...}}, "load_cell": {...}}``.
        load_cell_measures : "wall" (force carried by the wall) or "total" (reading behind a
            pressurised cannula); identification corrects a "total" reading.
        """
        path = Path(path)
        if load_cell_measures not in ("wall", "total"):
            raise ValueError(f"load_cell_measures must be 'wall' or 'total'; got {load_cell_measures!r}")
        names = [c.name for c in cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique; got {names}")
        if path.exists() and not overwrite:
            raise SessionError(f"{path}: file exists; refusing to overwrite a session (choose another --out)")
        if path.exists():
            _refuse_live_session(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # Built under a temporary name and renamed into place: a kill during creation never
        # leaves a partial file at ``path`` that would block run and resume.
        tmp = path.with_name(f".{path.name}.creating-{os.getpid()}")
        f = _create_h5(tmp, path)
        try:
            cls._build(f, specimen, cameras, protocol_text, rig or {}, instruments or {}, load_cell_measures)
            f.flush()
            f.swmr_mode = True
            os.replace(tmp, path)
        except BaseException:
            f.close()
            tmp.unlink(missing_ok=True)
            raise
        writer = cls(f, path)
        writer._fsync()
        log.info("created session %s", path)
        return writer

    @staticmethod
    def _build(f, specimen, cameras, protocol_text, rig, instruments, load_cell_measures) -> None:
        f.attrs["vfmlab_schema_version"] = SCHEMA_VERSION
        f.attrs["creator"] = f"vfmlab {_software_version()}"
        f.attrs["HDF5_Version"] = h5py.version.hdf5_version
        f.attrs["h5py_version"] = h5py.version.version
        f.attrs["file_time"] = _now_iso()
        f.attrs["default"] = "entry"
        entry = f.create_group("entry")
        entry.attrs["NX_class"] = "NXentry"
        entry.attrs["start_time"] = _now_iso()
        entry.attrs["software_version"] = _software_version()
        _stamp_writer(entry)
        entry.create_dataset("status", data=np.bytes_(b"running"), dtype=_STATUS_DTYPE)
        entry.create_dataset("end_time", data=np.bytes_(b""), dtype="S40")

        sample = entry.create_group("sample")
        sample.attrs["NX_class"] = "NXsample"
        sample["name"] = specimen.specimen_id
        for key in ("radius", "length", "thickness"):
            sample[key] = float(getattr(specimen, key))
            sample[key].attrs["units"] = "m"
        sample["notes"] = specimen.notes
        if specimen.ends:
            sample["ends"] = specimen.ends
            sample["ends"].attrs["source"] = specimen.ends_source

        inst = entry.create_group("instrument")
        inst.attrs["NX_class"] = "NXinstrument"
        inst["rig_settings"] = json.dumps(rig, sort_keys=True)
        for role in ("pressure", "load_cell"):
            g = inst.create_group(role)
            g.attrs["NX_class"] = "NXsensor"
            info = instruments.get(role, {})
            g.attrs["identity"] = str(info.get("identity", ""))
            g.attrs["settings"] = json.dumps(info.get("settings", {}), sort_keys=True)
        inst["load_cell"].attrs["measures"] = load_cell_measures
        cams = inst.create_group("cameras")
        cams.attrs["NX_class"] = "NXcollection"
        for cam in cameras:
            g = cams.create_group(cam.name)
            g.attrs["NX_class"] = "NXdetector"
            g.attrs["model"] = cam.model
            g.attrs["width"] = int(cam.width)
            g.attrs["height"] = int(cam.height)

        proto = entry.create_group("protocol")
        proto.attrs["NX_class"] = "NXnote"
        proto.attrs["type"] = "application/toml"
        proto["data"] = protocol_text
        proto.attrs["sha256"] = hashlib.sha256(protocol_text.encode("utf-8")).hexdigest()

        SessionWriter._build_growing(entry, cameras)
        res = entry.create_group("results")
        res.attrs["NX_class"] = "NXcollection"

    @staticmethod
    def _build_growing(entry: h5py.Group, cameras: Sequence[CameraSpec]) -> None:
        """Every dataset that grows (logs, steps, frames, events), created before SWMR mode."""
        logs = entry.create_group("log")
        logs.attrs["NX_class"] = "NXcollection"
        for channel, units in _LOG_CHANNELS.items():
            g = logs.create_group(channel)
            g.attrs["NX_class"] = "NXlog"
            _growable(g, "time", "f8", "s").attrs["start"] = "1970-01-01T00:00:00Z"
            _growable(g, "monotonic_time", "f8", "s")
            _growable(g, "value", "f8", units)
            _growable(g, "raw", _RAW_DTYPE, None)
            _growable(g, "seq", "i8", None)

        steps = entry.create_group("steps")
        steps.attrs["NX_class"] = "NXdata"
        steps.attrs["signal"] = "pressure"
        for name, (dtype, units) in _STEP_COLUMNS.items():
            _growable(steps, name, dtype, units or None, chunk=64)
        images = steps.create_group("images")
        calib = entry.create_group("calibration").create_group("images")
        for cam in cameras:
            for group in (images, calib):
                ds = group.create_dataset(
                    cam.name,
                    shape=(0, cam.height, cam.width),
                    maxshape=(None, cam.height, cam.width),
                    chunks=(1, cam.height, cam.width),
                    dtype=np.dtype(cam.dtype),
                    compression="gzip",
                    compression_opts=1,
                    shuffle=np.dtype(cam.dtype).itemsize > 1,
                )
                ds.attrs["units"] = "counts"

        events = entry.create_group("events")
        _growable(events, "time", "f8", "s", chunk=256)
        _growable(events, "kind", _EVENT_KIND_DTYPE, None, chunk=256)
        _growable(events, "message", _EVENT_MESSAGE_DTYPE, None, chunk=256)

    @classmethod
    def resume(cls, path: str | os.PathLike) -> SessionWriter:
        """Reopen an interrupted session (killed writer, power cut) to append to it.

        Refuses complete or aborted sessions and sessions whose writer is still alive.
        """
        path = Path(path)
        with open_session(path) as session:
            status = session.status
        if status != "interrupted":
            raise SessionError(f"{path}: session status is {status!r}; only an interrupted session can be resumed")
        clear_consistency_flags(path)
        try:
            f = h5py.File(path, "a", libver="latest")
        except OSError as exc:
            if "unable to lock file" not in str(exc):
                raise SessionError(f"{path}: cannot reopen for writing: {exc}") from None
            # Readers that have the interrupted file open (SWMR readers, a live view, 'vfmlab info'
            # in another terminal) hold HDF5's shared lock; they must not block resume. One writer
            # at a time is kept by the status check above (a live writer = "running").
            try:
                f = h5py.File(path, "a", libver="latest", locking=False)
            except OSError as exc2:
                raise SessionError(f"{path}: cannot reopen for writing: {exc2}") from None
        trimmed = _trim_partial_records(f["entry"])
        _stamp_writer(f["entry"])
        f.flush()
        f.swmr_mode = True
        f["entry/status"][()] = np.bytes_(b"running")
        writer = cls(f, path)
        writer.add_event("resume", f"session resumed by pid {os.getpid()}"
                         + (f"; dropped partial records: {', '.join(trimmed)}" if trimmed else ""))
        return writer

    # -- appending -----------------------------------------------------------------------
    @property
    def n_steps(self) -> int:
        return int(self._entry["steps/block"].shape[0])

    @property
    def camera_names(self) -> list[str]:
        return list(self._entry["steps/images"].keys())

    @property
    def n_calibration_views(self) -> int:
        """Calibration-board views already stored (a resumed session continues after them)."""
        calib = self._entry["calibration/images"]
        return int(min((calib[name].shape[0] for name in calib), default=0))

    def append_log(
        self,
        channel: str,
        t_monotonic: np.ndarray,
        t_wall: np.ndarray,
        value: np.ndarray,
        raw: Sequence[str] | None = None,
        seq: np.ndarray | None = None,
    ) -> None:
        """Append samples ``(n,)`` of one instrument channel ("pressure" in Pa, "force" in N)."""
        if channel not in _LOG_CHANNELS:
            raise ValueError(f"channel must be one of {sorted(_LOG_CHANNELS)}; got {channel!r}")
        t_monotonic = np.atleast_1d(np.asarray(t_monotonic, dtype=float))
        n = t_monotonic.shape[0]
        t_wall = np.atleast_1d(np.asarray(t_wall, dtype=float))
        value = np.atleast_1d(np.asarray(value, dtype=float))
        if t_wall.shape != (n,) or value.shape != (n,):
            raise ValueError(
                f"append_log: t_monotonic, t_wall and value must all have shape ({n},); "
                f"got {t_wall.shape} and {value.shape}"
            )
        raw_arr = np.array([_fixed(r, _RAW_DTYPE) for r in (raw if raw is not None else [""] * n)], dtype=_RAW_DTYPE)
        seq_arr = np.full(n, -1, dtype="i8") if seq is None else np.asarray(seq, dtype="i8")
        if raw_arr.shape != (n,) or seq_arr.shape != (n,):
            raise ValueError(f"append_log: raw and seq must have {n} entries")
        if n == 0:
            return
        g = self._entry["log"][channel]
        for name, data in (("time", t_wall), ("monotonic_time", t_monotonic), ("value", value),
                           ("raw", raw_arr), ("seq", seq_arr)):
            _append(g[name], data)
        self._f.flush()

    def add_step(self, step: StepRecord, images: Mapping[str, np.ndarray] | None = None) -> int:
        """Append one captured step with one frame per camera; returns its row index.

        All of the session's cameras must be given (a failed camera is the caller's error to
        report, not a silently missing frame). Flushed and fsynced before returning.
        """
        images = dict(images or {})
        expected = set(self.camera_names)
        if set(images) != expected:
            raise ValueError(
                f"add_step: images must be given for cameras {sorted(expected)}; got {sorted(images)}"
            )
        steps = self._entry["steps"]
        for name, frame in images.items():
            ds = steps["images"][name]
            frame = np.asarray(frame)
            if frame.shape != ds.shape[1:]:
                raise ValueError(f"add_step: camera {name!r} frame must have shape {ds.shape[1:]}; got {frame.shape}")
            _append(ds, frame[None].astype(ds.dtype, copy=False))
        # The table rows go last: a row exists only once its frames are written.
        for name in _STEP_COLUMNS:
            _append(steps[name], np.array([getattr(step, name)], dtype=steps[name].dtype))
        self._f.flush()
        self._fsync()
        return self.n_steps - 1

    def add_calibration_view(self, images: Mapping[str, np.ndarray]) -> int:
        """Append one calibration-board view (one frame per camera, a subset allowed); returns its index."""
        calib = self._entry["calibration/images"]
        unknown = set(images) - set(calib.keys())
        if unknown:
            raise ValueError(f"add_calibration_view: unknown cameras {sorted(unknown)}; known {sorted(calib.keys())}")
        index = max((calib[name].shape[0] for name in calib), default=0)
        for name in calib:
            ds = calib[name]
            frame = images.get(name)
            ds.resize((index + 1,) + ds.shape[1:])  # cameras not seeing this view keep a zero frame
            if frame is not None:
                ds[index] = np.asarray(frame).astype(ds.dtype, copy=False)
        self._f.flush()
        self._fsync()
        return index

    def add_event(self, kind: str, message: str) -> None:
        """Record an operator note or runner event (kind <= 32 bytes, message <= 512 bytes)."""
        import time

        events = self._entry["events"]
        _append(events["time"], np.array([time.time()]))
        _append(events["kind"], np.array([_fixed(kind, _EVENT_KIND_DTYPE)], dtype=_EVENT_KIND_DTYPE))
        _append(events["message"], np.array([_fixed(message, _EVENT_MESSAGE_DTYPE)], dtype=_EVENT_MESSAGE_DTYPE))
        self._f.flush()

    def set_status(self, status: str) -> None:
        if status not in _STATUSES:
            raise ValueError(f"status must be one of {_STATUSES}; got {status!r}")
        self._entry["status"][()] = np.bytes_(status.encode())
        if status != "running":
            self._entry["end_time"][()] = np.bytes_(_now_iso().encode())
        self._f.flush()
        self._fsync()

    def _fsync(self) -> None:
        try:
            with open(self.path, "rb+") as fh:
                os.fsync(fh.fileno())
        except OSError as exc:  # pragma: no cover - e.g. read-only media
            log.warning("fsync of %s failed: %s", self.path, exc)

    def close(self, status: str = "complete") -> None:
        if self._closed:
            return
        try:
            self.set_status(status)
        finally:
            self._f.close()
            self._closed = True

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close("complete" if exc_type is None else "aborted")


def incomplete_leftover(path: str | os.PathLike) -> bool:
    """True if ``path`` is a tiny file that is not a readable session: what a run killed while it
    created the file leaves (0 to a few dozen bytes, no data). Such a file may be replaced."""
    path = Path(path)
    try:
        if not path.is_file() or path.stat().st_size >= 4096:
            return False
    except OSError:
        return False
    try:
        open_session(path).close()
    except SessionError:
        return True
    return False


def _refuse_live_session(path: Path) -> None:
    """Two writers never share a file: refuse to replace a session another process is recording."""
    for _attempt in range(3):
        try:
            with open_session(path) as session:
                status = session.status
                pid = session.file["entry"].attrs.get("writer_pid", "?")
            break
        except SessionError:
            if incomplete_leftover(path):
                return  # the few bytes a killed creation left: nothing is recorded into it
            time.sleep(0.2)  # a reader can catch a live writer mid-append: look again
    else:
        with open(path, "rb") as fh:
            if fh.read(8) != b"\x89HDF\r\n\x1a\n":
                return  # not HDF5: not a session
        raise SessionError(f"{path}: an HDF5 file that cannot be read right now (a session being written?); "
                           "refusing to replace it")
    if status == "running":
        raise SessionError(f"{path}: a session is being recorded into this file right now (writer pid {pid}); "
                           "refusing to replace it")


def _trim_partial_records(entry: h5py.Group) -> list[str]:
    """Cut every table a killed writer may have left half-appended back to its complete rows.

    Log and event columns are appended one after another, and a step's frames are written before
    its table row, so after a kill the datasets of one table can differ in length by one append.
    Returns a description of what was dropped (empty if nothing).
    """
    dropped = []
    tables = [entry["log"][channel] for channel in _LOG_CHANNELS] + [entry["events"]]
    for group in tables:
        n = min(ds.shape[0] for ds in group.values())
        for ds in group.values():
            if ds.shape[0] > n:
                dropped.append(f"{ds.name}[{n}:{ds.shape[0]}]")
                ds.resize((n,) + ds.shape[1:])
    calib = entry["calibration/images"] if "calibration/images" in entry else {}
    n_views = min((ds.shape[0] for ds in calib.values()), default=0)
    for ds in calib.values():  # a view is complete once every camera has its frame
        if ds.shape[0] > n_views:
            dropped.append(f"{ds.name}[{n_views}:{ds.shape[0]}]")
            ds.resize((n_views,) + ds.shape[1:])
    steps = entry["steps"]
    n_rows = min(steps[name].shape[0] for name in _STEP_COLUMNS)
    for ds in [steps[name] for name in _STEP_COLUMNS] + list(steps["images"].values()):
        if ds.shape[0] > n_rows:
            dropped.append(f"{ds.name}[{n_rows}:{ds.shape[0]}]")
            ds.resize((n_rows,) + ds.shape[1:])
    return dropped


# -- reading ---------------------------------------------------------------------------------

def _decode(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.dtype.kind in "SO":
        return np.array([v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v) for v in value.ravel()],
                        dtype=object).reshape(value.shape).astype(str)
    return value


def _read(ds: h5py.Dataset) -> Any:
    return _decode(ds[()])


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def _start_ticks(pid: int) -> int:
    """Start time of process ``pid`` in clock ticks since boot (/proc/<pid>/stat field 22), or -1."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return -1


def _stamp_writer(entry: h5py.Group) -> None:
    """Record who writes: pid, host, boot id and the process start time (a reused pid is not us)."""
    entry.attrs["writer_pid"] = os.getpid()
    entry.attrs["writer_host"] = socket.gethostname()
    entry.attrs["writer_boot_id"] = _boot_id()
    entry.attrs["writer_start_ticks"] = _start_ticks(os.getpid())


def _writer_alive(pid: int, host: str, boot_id: str = "", start_ticks: int = -1) -> bool:
    """Is the process that recorded ``status = running`` still running (on this machine, this boot)?"""
    if host != socket.gethostname():
        return False  # another machine wrote it; nobody here is still writing
    if boot_id and _boot_id() and boot_id != _boot_id():
        return False  # the machine rebooted since: every writer of that boot is gone
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    if start_ticks >= 0 and _start_ticks(pid) not in (-1, start_ticks):
        return False  # the pid was reused by another process
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
        return state != "Z"  # a zombie has exited
    except OSError:
        return True


# What h5py raises when a dataset or attribute of a file that opened cannot be read (bit flips,
# a truncated copy, a foreign writer): metadata checksum errors surface as KeyError or RuntimeError,
# undecodable data as OSError, malformed content as ValueError/TypeError/IndexError.
_READ_FAULTS = (OSError, KeyError, RuntimeError, ValueError, TypeError, IndexError, AttributeError)


def _reads(what: str) -> Callable:
    """Decorate a :class:`Session` reader: a read fault becomes a :class:`DamagedSessionError` naming ``what``.

    ``what`` names the part of the file read, e.g. ``"the step table (/entry/steps)"``; it may use the
    reader's positional arguments as ``{0}``, ``{1}``.
    """
    def decorate(method: Callable) -> Callable:
        @functools.wraps(method)
        def guarded(self: Session, *args: Any, **kwargs: Any) -> Any:
            try:
                return method(self, *args, **kwargs)
            except SessionError:
                raise
            except _READ_FAULTS as exc:
                raise damaged_error(self.path, what.format(*args), exc) from None
        return guarded
    return decorate


def damaged_error(path: Path, what: str, exc: BaseException) -> DamagedSessionError:
    """The one-line error for a part of a session file that cannot be read, with the way to see the rest."""
    reason = str(exc).strip().strip("'\"") or type(exc).__name__
    return DamagedSessionError(f"{path}: {what} is damaged and cannot be read ({reason}); "
                               f"'vfmlab info {path}' lists what is still readable")


class Session:
    """A validated, read-only view of a session file. Obtain with :func:`open_session`.

    Every reader raises :class:`DamagedSessionError` (naming the part of the file) when the file
    opened but that part cannot be read; the other parts stay readable.
    """

    def __init__(self, h5file: h5py.File, path: Path):
        self._f = h5file
        self.path = path
        self._entry = h5file["entry"]

    # -- identity and status --------------------------------------------------------------
    @property
    def file(self) -> h5py.File:
        """The underlying h5py file (read-only)."""
        return self._f

    @property
    @_reads("the schema version (/@vfmlab_schema_version)")
    def schema_version(self) -> str:
        return str(_decode(self._f.attrs["vfmlab_schema_version"]))

    @property
    @_reads("the session status (/entry/status)")
    def recorded_status(self) -> str:
        """The status the writer last recorded: running | complete | aborted | interrupted."""
        return str(_read(self._entry["status"]))

    @property
    @_reads("the session status (/entry/status)")
    def status(self) -> str:
        """complete | aborted | interrupted (recorded, or the writer died while running) | running."""
        status = self.recorded_status
        if status == "running":
            attrs = self._entry.attrs
            pid = int(attrs.get("writer_pid", -1))
            host = str(_decode(attrs.get("writer_host", "")))
            if not _writer_alive(pid, host, str(_decode(attrs.get("writer_boot_id", ""))),
                                 int(attrs.get("writer_start_ticks", -1))):
                return "interrupted"
        return status

    @property
    @_reads("the start time (/entry@start_time)")
    def start_time(self) -> str:
        return str(_decode(self._entry.attrs.get("start_time", "")))

    @property
    @_reads("the software version (/entry@software_version)")
    def software_version(self) -> str:
        return str(_decode(self._entry.attrs.get("software_version", "")))

    @property
    @_reads("the specimen geometry (/entry/sample)")
    def specimen(self) -> SpecimenInfo:
        s = self._entry["sample"]
        ends = str(_read(s["ends"])) if "ends" in s else ""
        return SpecimenInfo(
            specimen_id=str(_read(s["name"])),
            radius=float(s["radius"][()]),
            length=float(s["length"][()]),
            thickness=float(s["thickness"][()]),
            notes=str(_read(s["notes"])),
            ends=ends if ends in ("clamped", "free") else "",  # an unreadable value counts as unknown
            ends_source=str(_decode(s["ends"].attrs.get("source", ""))) if ends in ("clamped", "free") else "",
        )

    @property
    @_reads("the protocol (/entry/protocol/data)")
    def protocol_text(self) -> str:
        return str(_read(self._entry["protocol/data"]))

    @property
    @_reads("the protocol checksum (/entry/protocol@sha256)")
    def protocol_sha256(self) -> str:
        return str(_decode(self._entry["protocol"].attrs.get("sha256", "")))

    @property
    @_reads("the load-cell setting (/entry/instrument/load_cell@measures)")
    def load_cell_measures(self) -> str:
        return str(_decode(self._entry["instrument/load_cell"].attrs.get("measures", "wall")))

    @property
    @_reads("the instrument records (/entry/instrument)")
    def instruments(self) -> dict[str, dict[str, Any]]:
        out = {}
        for role in ("pressure", "load_cell"):
            g = self._entry["instrument"][role]
            out[role] = {
                "identity": str(_decode(g.attrs.get("identity", ""))),
                "settings": json.loads(_decode(g.attrs.get("settings", "{}")) or "{}"),
            }
        return out

    @property
    @_reads("the rig settings (/entry/instrument/rig_settings)")
    def rig_settings(self) -> dict[str, Any]:
        return json.loads(str(_read(self._entry["instrument/rig_settings"])) or "{}")

    @property
    @_reads("the camera records (/entry/instrument/cameras)")
    def cameras(self) -> list[CameraSpec]:
        out = []
        for name, g in self._entry["instrument/cameras"].items():
            dtype = self._entry["steps/images"][name].dtype.name if name in self._entry["steps/images"] else "uint8"
            out.append(CameraSpec(name, str(_decode(g.attrs["model"])), int(g.attrs["width"]),
                                  int(g.attrs["height"]), dtype))
        return out

    @property
    @_reads("the step images (/entry/steps/images)")
    def image_cameras(self) -> dict[str, tuple[int, int]]:
        """Cameras with step images and their frame size ``(height, width)`` px."""
        images = self._entry["steps"].get("images")
        return {} if images is None else {name: tuple(int(n) for n in ds.shape[1:3]) for name, ds in images.items()}

    @property
    @_reads("the camera records (/entry/instrument/cameras)")
    def camera_names(self) -> list[str]:
        return list(self._entry["instrument/cameras"].keys())

    # -- steps, images, logs ---------------------------------------------------------------
    @property
    @_reads("the step table (/entry/steps)")
    def n_steps(self) -> int:
        """Complete step rows (a writer killed mid-append may have left a longer column)."""
        steps = self._entry["steps"]
        return int(min(steps[name].shape[0] for name in _STEP_COLUMNS))

    @property
    @_reads("the step table (/entry/steps)")
    def steps(self) -> dict[str, np.ndarray]:
        """The step table: ``(n_steps,)`` arrays per column, plus ``active`` (not superseded)."""
        g = self._entry["steps"]
        n = self.n_steps
        table = {name: g[name][:n] for name in _STEP_COLUMNS}
        active = np.ones(n, dtype=bool)
        retaken = table["supersedes"][table["supersedes"] >= 0]
        active[retaken[retaken < n]] = False
        table["active"] = active
        return table

    @_reads("the image of camera {0!r} at step row {1} (/entry/steps/images/{0})")
    def image(self, camera: str, step: int) -> np.ndarray:
        """Frame of ``camera`` at step row ``step``, shape (H, W)."""
        images = self._entry["steps/images"]
        if camera not in images:
            raise SessionError(f"{self.path}: no camera {camera!r}; cameras are {sorted(images)}")
        if not 0 <= step < self.n_steps:
            raise SessionError(f"{self.path}: step {step} out of range 0..{self.n_steps - 1}")
        return images[camera][step]

    @_reads("the calibration images of camera {0!r} (/entry/calibration/images/{0})")
    def calibration_images(self, camera: str) -> np.ndarray:
        """Calibration-board frames of ``camera``, shape (n_views, H, W)."""
        return self._entry["calibration/images"][camera][()]

    def log(self, channel: str) -> dict[str, np.ndarray]:
        """The continuous log of "pressure" (Pa) or "force" (N): time, t_monotonic, value, raw, seq."""
        if channel not in _LOG_CHANNELS:
            raise ValueError(f"channel must be one of {sorted(_LOG_CHANNELS)}; got {channel!r}")
        return self._log(channel)

    @_reads("the {0} log (/entry/log/{0})")
    def _log(self, channel: str) -> dict[str, np.ndarray]:
        g = self._entry["log"][channel]
        n = min(g[k].shape[0] for k in ("time", "monotonic_time", "value", "raw", "seq"))
        return {
            "t_wall": g["time"][:n],
            "t_monotonic": g["monotonic_time"][:n],
            "value": g["value"][:n],
            "raw": _decode(g["raw"][:n]),
            "seq": g["seq"][:n],
        }

    @_reads("the event log (/entry/events)")
    def events(self) -> list[dict[str, Any]]:
        """Events (time s, kind, message), oldest first; kind "warning" holds plausibility warnings (decision 0007)."""
        g = self._entry.get("events")
        if g is None:
            return []
        n = min(g[k].shape[0] for k in ("time", "kind", "message"))
        times, kinds, messages = g["time"][:n], _decode(g["kind"][:n]), _decode(g["message"][:n])
        return [{"time": float(t), "kind": str(k), "message": str(m)} for t, k, m in zip(times, kinds, messages)]

    # -- derived results ---------------------------------------------------------------------
    @_reads("the list of derived results (/entry/results)")
    def results(self, kind: str | None = None) -> list[str]:
        """Names of derived result groups (e.g. "markers_001"), oldest first, optionally of one kind."""
        res = self._entry.get("results")
        if res is None:
            return []
        names = sorted(res.keys(), key=lambda n: (str(_decode(res[n].attrs.get("date", ""))), n))
        if kind is not None:
            names = [n for n in names if _decode(res[n].attrs.get("kind", "")) == kind]
        return names

    def result(self, name: str) -> dict[str, Any]:
        """One result: ``{"name", "kind", "arrays": {...}, "parameters": {...}, "attrs": {...}, "units": {...}}``."""
        if name not in self.results():
            raise SessionError(f"{self.path}: no result {name!r}; results are {self.results()}")
        return self._result(name)

    @_reads("the result {0!r} (/entry/results/{0})")
    def _result(self, name: str) -> dict[str, Any]:
        g = self._entry["results"][name]
        arrays, units = {}, {}
        for key, ds in g.items():
            if isinstance(ds, h5py.Dataset):
                arrays[key] = _read(ds)
                if "units" in ds.attrs:
                    units[key] = str(_decode(ds.attrs["units"]))
        attrs = {k: _decode(v) for k, v in g.attrs.items() if k not in ("parameters", "NX_class")}
        for key, value in list(attrs.items()):
            if isinstance(value, str) and key.endswith("_json"):
                attrs[key[:-5]] = json.loads(value)
                del attrs[key]
        _check_result_arrays(str(attrs.get("kind", "")), arrays)
        return {
            "name": name,
            "kind": str(attrs.get("kind", "")),
            "arrays": arrays,
            "parameters": json.loads(str(_decode(g.attrs.get("parameters", "{}")))),
            "attrs": attrs,
            "units": units,
        }

    def latest(self, kind: str) -> dict[str, Any] | None:
        """The newest result of ``kind``, or None."""
        names = self.results(kind)
        return self.result(names[-1]) if names else None

    # -- lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _check_result_arrays(kind: str, arrays: Mapping[str, Any]) -> None:
    """Shapes the readers of a result rely on; ValueError (reported as damage) when they do not hold."""
    if kind == "markers":
        if "positions" not in arrays:
            raise ValueError("a markers result must hold 'positions'; it has " + str(sorted(arrays)))
        pos = np.asarray(arrays["positions"])
        if pos.ndim != 3 or pos.shape[2] != 3 or pos.dtype.kind not in "fiu":
            raise ValueError(f"positions must be numbers of shape (n_steps, n_markers, 3); found {pos.dtype.name} "
                             f"of shape {pos.shape}")
        for key, shape in (("visible", pos.shape[:2]), ("step_index", pos.shape[:1]), ("step_number", pos.shape[:1])):
            if key in arrays and np.shape(arrays[key]) != shape:
                raise ValueError(f"{key} must have shape {shape} to match positions; found {np.shape(arrays[key])}")
    elif kind == "identification" and "parameters" in arrays:
        values, names = np.asarray(arrays["parameters"]), np.asarray(arrays.get("parameter_names", []))
        if values.ndim != 1 or values.dtype.kind not in "fiu" or ("parameter_names" in arrays
                                                                  and names.shape != values.shape):
            raise ValueError(f"parameters must be numbers of shape (n_parameters,) matching parameter_names; found "
                             f"{values.dtype.name} of shape {values.shape} for {names.size} names")


def _h5_open_read(path: Path) -> h5py.File:
    """``h5py.File(path, "r")``, waiting (bounded: the lock timeout in all) while other jobs append results.

    Raises :class:`LockTimeout` when they hold the file longer than that.
    """
    deadline = time.monotonic() + lock_timeout()
    while True:
        try:
            return _h5_open_read_once(path)
        except OSError as exc:
            if "unable to lock file" not in str(exc):
                raise
        # Another job is appending a result (an exclusive lock for a moment): wait for it, then open
        # again; a third job may take the lock in between (1 open in ~30 with 6 concurrent writers), so loop.
        with open(path, "rb") as fh:
            wait_lock(fh.fileno(), path, exclusive=False, what="read", timeout=max(0.0, deadline - time.monotonic()))
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _h5_open_read_once(path: Path) -> h5py.File:
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        if "already open for write" in str(exc):
            # A live SWMR writer, or one killed mid-session: SWMR readers see a consistent file.
            return h5py.File(path, "r", libver="latest", swmr=True)
        raise


PREFLIGHT_TIMEOUT = 20.0  # s; walking the structure of a sound session takes well under a second


def _walk_structure(path: Path) -> None:
    """Read every object header and attribute of the file (not the data)."""
    with _h5_open_read(path) as f:
        def visit(_name: str, obj: Any) -> None:
            for key in obj.attrs:
                obj.attrs[key]
        for key in f.attrs:
            f.attrs[key]
        f.visititems(visit)


#: Stat fields that change whenever a file's bytes do (or the file is replaced).
_StatKey = tuple[int, int, int, int, int]
#: A file whose last change is older than this (s) when its structure walk starts keeps the walk's
#: verdict while its stat is unchanged: any later write then moves its mtime/ctime by more than the
#: time stamps' resolution (the kernel's coarse clock tick, <= 10 ms, plus the file system's: 1 ns on
#: ext4/xfs/btrfs/tmpfs, 2 s on FAT), so "same stat" means "same bytes". A file changed more recently
#: is simply walked again at its next open.
QUIET_BEFORE_WALK = 2.5
#: Files of this process whose structure walk finished cleanly: real path -> stat key before the walk.
_verified: dict[str, _StatKey] = {}
#: The one structure walk started ahead by :func:`start_preflight`: (real path, child pid, stat key,
#: quiet, monotonic start time, pid of the process that forked it), or None.
_pending: tuple[str, int, _StatKey, bool, float, int] | None = None
_drop_registered = False


def _stat_key(path: Path) -> tuple[_StatKey, bool]:
    """The file's stat key and whether it had been quiet (unchanged for ``QUIET_BEFORE_WALK`` s)."""
    now = time.time()
    st = os.stat(path)
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    return key, now - max(st.st_mtime_ns, st.st_ctime_ns) * 1e-9 > QUIET_BEFORE_WALK


def start_preflight(path: str | os.PathLike) -> None:
    """Start the structure walk of :func:`open_session` on ``path`` now, in a child process, so that it
    runs while this process does other work (imports, option checks) on the machine's other core.

    Nothing of the file is read by this process: the next :func:`open_session` of ``path`` waits for
    this walk's verdict (and walks again if the file changed meanwhile). Does nothing where there is
    no ``fork`` or the file cannot be stat'ed (``open_session`` reports that).
    """
    global _pending, _drop_registered
    if not hasattr(os, "fork"):  # pragma: no cover - Windows: no preflight
        return
    _drop_pending()
    path = Path(path)
    try:
        real = os.path.realpath(path)
        key, quiet = _stat_key(path)
    except OSError:
        return
    if _verified.get(real) == key:
        return
    _pending = (real, _fork_walk(path, PREFLIGHT_TIMEOUT), key, quiet, time.monotonic(), os.getpid())
    if not _drop_registered:
        atexit.register(_drop_pending)
        _drop_registered = True


def _drop_pending() -> None:
    """Kill and reap a walk started ahead that nobody waited for (only this process's own child)."""
    global _pending
    if _pending is not None:
        pid, owner = _pending[1], _pending[5]
        _pending = None
        if owner == os.getpid():
            with contextlib.suppress(OSError):
                os.kill(pid, 9)
                os.waitpid(pid, 0)


def _preflight(path: Path, timeout: float | None = None) -> None:
    """Walk the file's structure in a child process first: HDF5 can loop without end (holding the
    interpreter) on some corrupted headers, which no exception or signal can interrupt.

    A child that does not finish within ``timeout`` s (default ``PREFLIGHT_TIMEOUT``, read at the
    call) is killed and the file reported as damaged;
    every other outcome (including errors, which the parent reports with context) passes.

    The walk is not repeated for a file this process has walked cleanly and that has not changed
    since (``_verified``: same stat key, and quiet for ``QUIET_BEFORE_WALK`` s before the walk, so
    the key cannot miss a write); a walk :func:`start_preflight` began on the same unchanged file is
    waited for instead of starting another. Either way no byte of a file reaches this process's
    HDF5 library before a walk of those very bytes has finished.
    """
    global _pending
    timeout = PREFLIGHT_TIMEOUT if timeout is None else timeout
    if not hasattr(os, "fork"):  # pragma: no cover - Windows: no preflight
        return
    real = os.path.realpath(path)
    try:
        key, quiet = _stat_key(path)
    except OSError:  # gone meanwhile: walk anyway, the open after it says what is wrong
        key, quiet = None, False
    if key is not None and _verified.get(real) == key:
        return
    remaining = timeout
    if _pending is not None and _pending[0] == real and _pending[2] == key and _pending[5] == os.getpid():
        _, pid, _, quiet, started, _ = _pending
        _pending = None
        remaining = max(timeout - (time.monotonic() - started), 0.0)
    else:
        _drop_pending()
        pid = _fork_walk(path, timeout)
    status = _wait_child(pid, remaining)
    if status is None:
        raise DamagedSessionError(f"{path}: damaged session file: HDF5 does not finish reading its structure "
                                  f"(gave up after {timeout:g} s)")
    if status == 0 and quiet and _unchanged(path, key):  # walked cleanly, and nothing wrote meanwhile
        _verified[real] = key


def _unchanged(path: Path, key: _StatKey | None) -> bool:
    try:
        return key is not None and _stat_key(path)[0] == key
    except OSError:
        return False


def _fork_walk(path: Path, timeout: float) -> int:
    """Fork a child that walks ``path``'s structure (exit 0: clean, 3: an error) and return its pid.

    The child also ends itself by SIGALRM after ``timeout`` s (+2), so that no parent fate (killed,
    interrupted) can leave it looping in HDF5.
    """
    import signal
    import threading

    # Ctrl-C during fork() would be raised inside logging's at-fork hook and lost: hold it until after.
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 0
            try:
                signal.signal(signal.SIGALRM, signal.SIG_DFL)
                signal.alarm(int(timeout) + 2)
                _walk_structure(path)
            except BaseException:  # noqa: BLE001 - the parent reports errors itself
                code = 3
            os._exit(code)
    finally:
        if main_thread:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    return pid


def _wait_child(pid: int, timeout: float) -> int | None:
    """Wait up to ``timeout`` s for child ``pid``; its exit code (-1: killed by a signal), or None
    after killing it when it did not end in time. Killed on any exception too."""
    deadline = time.monotonic() + timeout
    try:
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                return os.WEXITSTATUS(status) if os.WIFEXITED(status) else -1
            if time.monotonic() >= deadline:
                break
            time.sleep(0.001)
    except BaseException:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        raise
    os.kill(pid, 9)
    os.waitpid(pid, 0)
    return None


def _open_possibly_growing(path: Path) -> h5py.File:
    """The HDF5 file opened for reading; a SessionError naming a truncated or damaged file.

    A file a live writer is appending to looks truncated to a reader that catches it mid-append
    (about 1 open in 25 against a writer appending continuously): if the file grew meanwhile it is
    opened again (up to 3 times), so only a file that stays short is reported as truncated.
    """
    for attempt in range(4):
        size = path.stat().st_size
        try:
            return _h5_open_read(path)
        except LockTimeout as exc:
            raise SessionError(str(exc)) from None
        except OSError as exc:
            reason = str(exc)
        if not ("truncated" in reason or "eof" in reason.lower()):
            raise SessionError(f"{path}: damaged HDF5 file, cannot be opened ({reason})") from None
        if attempt < 3:
            time.sleep(0.05)
            if path.stat().st_size != size:
                continue
        raise SessionError(f"{path}: the file is truncated (incomplete copy or disk full?); cannot read it") from None
    raise AssertionError("unreachable")  # pragma: no cover


def open_session(path: str | os.PathLike) -> Session:
    """Open and validate a session file for reading.

    Raises
    ------
    SessionError
        With one readable sentence when the file is missing, not HDF5, truncated or damaged,
        not a vfmlab session, of an unsupported schema version, or lacks a required group.
    """
    path = Path(path)
    if not path.exists():
        raise SessionError(f"{path}: no such file")
    if path.is_dir():
        raise SessionError(f"{path}: is a directory, not a session file")
    try:
        recover(path)  # roll back a result write that a killed job left unfinished
    except (JournalError, LockTimeout) as exc:
        raise SessionError(str(exc)) from None
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head != b"\x89HDF\r\n\x1a\n":
        raise SessionError(f"{path}: not a session file (not HDF5: the file does not start with the HDF5 signature)")
    _preflight(path)
    f = _open_possibly_growing(path)
    try:
        _validate(f, path)
    except SessionError:
        f.close()
        raise
    except _READ_FAULTS as exc:
        f.close()
        raise DamagedSessionError(f"{path}: damaged session file: its required structure cannot be read ({exc})") \
            from None
    return Session(f, path)


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


def _store_array(group: h5py.Group, key: str, value: Any) -> h5py.Dataset:
    arr = np.asarray(value)
    if arr.dtype.kind in "US" or (arr.dtype.kind == "O" and all(isinstance(v, str) for v in arr.ravel())):
        return group.create_dataset(key, data=arr.astype(str).astype(object), dtype=h5py.string_dtype())
    if arr.dtype.kind == "O":
        raise TypeError(f"write_result: array {key!r} has dtype object; only numeric, bool and str arrays are stored")
    kwargs = {"compression": "gzip", "compression_opts": 4} if arr.size > 1024 else {}
    return group.create_dataset(key, data=arr, **kwargs)


def write_result(
    path: str | os.PathLike,
    kind: str,
    arrays: Mapping[str, Any],
    parameters: Mapping[str, Any],
    attrs: Mapping[str, Any] | None = None,
    units: Mapping[str, str] | None = None,
) -> str:
    """Append a derived result as ``/entry/results/<kind>_NNN`` (never overwrites); returns its name.

    ``parameters`` (the settings that produced it) is stored as JSON; ``attrs`` values that are
    dicts or lists are stored as JSON in ``<key>_json`` and decoded again by :meth:`Session.result`.
    """
    if not kind.isidentifier():
        raise ValueError(f"kind must be an identifier like 'markers'; got {kind!r}")
    path = Path(path)
    with open_session(path) as session:
        if session.status == "running":
            raise SessionError(f"{path}: the session is still being written; add results once it has finished")
        interrupted = session.status == "interrupted"
    prepare = None
    if interrupted:
        # The writer is gone: clearing its "open for write" flag is safe (and journaled, so a
        # kill right after leaves the file as it was); resume still works after.
        def prepare(jf) -> None:
            jf.save_original(0, 64)
            clear_consistency_flags(path)
    try:
        with journaled_h5(path, prepare=prepare) as f:
            name = _write_result_group(f, kind, arrays, parameters, attrs, units)
    except LockTimeout as exc:
        raise SessionWriteError(str(exc)) from None
    except OSError as exc:
        raise SessionWriteError(_write_failure(path, exc)) from None
    log.info("wrote result %s to %s", name, path)
    return name


def _write_result_group(f: h5py.File, kind: str, arrays: Mapping[str, Any], parameters: Mapping[str, Any],
                        attrs: Mapping[str, Any] | None, units: Mapping[str, str] | None) -> str:
    res = f["entry"].require_group("results")
    existing = [n for n in res if n.startswith(kind + "_")]
    number = 1 + max((int(n.rsplit("_", 1)[1]) for n in existing if n.rsplit("_", 1)[1].isdigit()), default=0)
    name = f"{kind}_{number:03d}"
    g = res.create_group(name)
    g.attrs["NX_class"] = "NXprocess"
    g.attrs["kind"] = kind
    g.attrs["program"] = "vfmlab"
    g.attrs["version"] = _software_version()
    g.attrs["date"] = _now_iso()
    g.attrs["parameters"] = json.dumps(dict(parameters), sort_keys=True, default=_json_default)
    for key, value in (attrs or {}).items():
        if isinstance(value, (dict, list, tuple)):
            g.attrs[f"{key}_json"] = json.dumps(value, default=_json_default)
        elif value is None:
            g.attrs[key] = "None"
        else:
            g.attrs[key] = value
    for key, value in arrays.items():
        ds = _store_array(g, key, value)
        if units and key in units:
            ds.attrs["units"] = units[key]
    return name


def _write_failure(path: Path, exc: OSError) -> str:
    """One sentence for a result write that failed (and was rolled back)."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        free = shutil.disk_usage(path.parent).free
        needed = getattr(exc, "needed", 0)
        return (f"{path}: disk full while writing the result ({_size(free)} free"
                + (f", about {_size(needed)} more needed" if needed else "")
                + "); the session was left exactly as it was before. Free some space and run the command again")
    return f"{path}: cannot write the result ({exc}); the session was left exactly as it was before"


def _size(nbytes: float) -> str:
    """A byte count for people: kB below 1 MB, MB below 1 GB, else GB."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6)):
        if nbytes >= scale:
            return f"{nbytes / scale:.1f} {unit}"
    return f"{max(nbytes, 0) / 1e3:.0f} kB"


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot store {type(obj).__name__} as JSON")
