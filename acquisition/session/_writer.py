"""Writing a session file: the one crash-safe, context-managed :class:`SessionWriter`."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import os
import re
import shutil
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.session._fence import MARGIN, failure_errno, fence, is_write_failure, reserve, vfd_handle
from acquisition.session._guards import _stamp_writer
from acquisition.session._reader import incomplete_leftover, open_session
from acquisition.session._recovery import _partial_records, clear_consistency_flags
from acquisition.session._schema import (
    _EVENT_KIND_DTYPE,
    _EVENT_MESSAGE_DTYPE,
    _LOG_CHANNELS,
    _LOG_CHUNK,
    _RAW_DTYPE,
    _STATUS_DTYPE,
    _STATUSES,
    _STEP_COLUMNS,
    SCHEMA_VERSION,
    CameraSpec,
    SessionError,
    SpecimenInfo,
    StepRecord,
    _fixed,
    _now_iso,
    _software_version,
)

log = logging.getLogger("acquisition.session")


def _create_h5(tmp: Path, path: Path) -> h5py.File:
    """A new HDF5 file at ``tmp``; a failure names ``path`` (what the user asked for), not the temporary name."""
    try:
        return h5py.File(tmp, "w", libver=("v110", "v110"))
    except OSError as exc:
        found = re.search(r"errno = (\d+)", str(exc))
        code = int(found.group(1)) if found else (exc.errno or errno.EIO)
        raise OSError(code, f"cannot create the file: {os.strerror(code)}", str(path)) from None


def _growable(group: h5py.Group, name: str, dtype: Any, units: str | None, chunk: int = _LOG_CHUNK) -> h5py.Dataset:
    ds = group.create_dataset(name, shape=(0,), maxshape=(None,), chunks=(chunk,), dtype=dtype)
    if units is not None:
        ds.attrs["units"] = units
    return ds


def _put(ds: h5py.Dataset, index: int, values: np.ndarray) -> None:
    """Write ``values`` at rows ``index:``, growing ``ds`` if needed (never shrinking it)."""
    end = index + len(values)
    if ds.shape[0] < end:
        ds.resize((end,) + ds.shape[1:])
    ds[index:end] = values


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
        self._failed: OSError | None = None  # the failed disk write that stopped this writer
        self._fd = vfd_handle(h5file)

    @contextlib.contextmanager
    def _disk(self, what: str, nbytes: int = 0) -> Iterator[None]:
        """Run HDF5 writes; a failed disk write stops the writer as a kill at that write would.

        The file is fenced (``_fence``): it keeps every record completed before, opens, reads as
        "interrupted" and is resumable. Raises OSError (ENOSPC for a full disk) saying so.
        """
        if self._failed is not None:
            raise OSError(self._failed.errno, f"{self.path}: the writer stopped at an earlier failed write "
                                              f"({self._failed.strerror})")
        try:
            reserve(self._fd, nbytes)  # a full disk is found here, before HDF5 writes a byte
        except OSError as exc:
            raise OSError(exc.errno, f"{exc.strerror} while writing {what} ({nbytes / 1e6:.1f} MB and a margin "
                                     f"needed); nothing of it was written and the session keeps every step "
                                     f"completed before", str(self.path)) from None
        try:
            yield
        except Exception as exc:
            if not is_write_failure(exc):
                raise
            code = failure_errno(exc)
            fence(self._f, self._fd)
            self._closed = True
            self._failed = OSError(code, f"{os.strerror(code)} while writing {what}; the session keeps every "
                                         f"step completed before and can be resumed once the disk has room")
            log.error("%s: %s", self.path, self._failed.strerror)
            raise OSError(code, self._failed.strerror, str(self.path)) from None

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
        free = shutil.disk_usage(path.parent).free
        if free < MARGIN:  # HDF5 must not meet a full disk while it lays the file out
            raise OSError(errno.ENOSPC, f"cannot create the file: disk full ({free / 1e6:.1f} MB free)", str(path))
        f = _create_h5(tmp, path)
        fd = vfd_handle(f)
        try:
            cls._build(f, specimen, cameras, protocol_text, rig or {}, instruments or {}, load_cell_measures)
            f.flush()
            f.swmr_mode = True
            reserve(fd, 0)
            os.replace(tmp, path)
        except BaseException as exc:
            if isinstance(exc, Exception) and is_write_failure(exc):
                fence(f, fd)
            else:
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
        entry.attrs["session_uuid"] = uuid.uuid4().hex  # binds the derived results beside the file to it
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
        clear_consistency_flags(path)  # one 64-byte write of the superblock
        # Opened straight in SWMR-write mode: every later write keeps the file readable at each
        # instant, so a kill at any write of resume leaves a session that opens and resumes again.
        f = _open_swmr_write(path)
        partial = _partial_records(f["entry"])
        writer = cls(f, path)
        with writer._disk("the writer's identity"):
            _stamp_writer(f["entry"])
            f["entry/status"][()] = np.bytes_(b"running")
            f.flush()
        writer.add_event("resume", f"session resumed by pid {os.getpid()}"
                         + (f"; dropped partial records: {', '.join(partial)}" if partial else ""))
        return writer

    # -- appending -----------------------------------------------------------------------
    @property
    def n_steps(self) -> int:
        return self.n_rows_complete()

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
        with self._disk(f"the {channel} log", 128 * n):
            g = self._entry["log"][channel]
            row = min(ds.shape[0] for ds in g.values())  # past the last complete sample (a kill may leave more)
            for name, data in (("time", t_wall), ("monotonic_time", t_monotonic), ("value", value),
                               ("raw", raw_arr), ("seq", seq_arr)):
                _put(g[name], row, data)
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
        frames = {}
        for name, frame in images.items():  # every frame checked before anything is written
            ds = steps["images"][name]
            frame = np.asarray(frame)
            if frame.shape != ds.shape[1:]:
                raise ValueError(f"add_step: camera {name!r} frame must have shape {ds.shape[1:]}; got {frame.shape}")
            frames[name] = frame[None].astype(ds.dtype, copy=False)
        row = self.n_rows_complete()
        with self._disk(f"step row {row}", sum(f.nbytes for f in frames.values()) + 4096):
            # Frames first, written at the row's index (a frame a killed writer left there is replaced),
            # the table row last: a row exists only once its frames are written.
            for name, frame in frames.items():
                _put(steps["images"][name], row, frame)
            for name in _STEP_COLUMNS:
                _put(steps[name], row, np.array([getattr(step, name)], dtype=steps[name].dtype))
            self._f.flush()
        self._fsync()
        return row

    def n_rows_complete(self) -> int:
        """Step rows complete in every column and every camera (what readers count as steps)."""
        steps = self._entry["steps"]
        return int(min([steps[name].shape[0] for name in _STEP_COLUMNS]
                       + [ds.shape[0] for ds in steps["images"].values()]))

    def add_calibration_view(self, images: Mapping[str, np.ndarray]) -> int:
        """Append one calibration-board view (one frame per camera, a subset allowed); returns its index."""
        calib = self._entry["calibration/images"]
        unknown = set(images) - set(calib.keys())
        if unknown:
            raise ValueError(f"add_calibration_view: unknown cameras {sorted(unknown)}; known {sorted(calib.keys())}")
        index = self.n_calibration_views
        nbytes = sum(int(np.prod(ds.shape[1:])) * ds.dtype.itemsize for ds in calib.values())
        with self._disk(f"calibration view {index}", nbytes):
            for name in calib:
                ds = calib[name]
                frame = images.get(name)
                if ds.shape[0] < index + 1:
                    ds.resize((index + 1,) + ds.shape[1:])  # cameras not seeing this view keep a zero frame
                ds[index] = (np.zeros(ds.shape[1:], ds.dtype) if frame is None
                             else np.asarray(frame).astype(ds.dtype, copy=False))
            self._f.flush()
        self._fsync()
        return index

    def add_event(self, kind: str, message: str) -> None:
        """Record an operator note or runner event (kind <= 32 bytes, message <= 512 bytes)."""
        import time

        with self._disk("the event log"):
            events = self._entry["events"]
            row = min(ds.shape[0] for ds in events.values())
            _put(events["time"], row, np.array([time.time()]))
            _put(events["kind"], row, np.array([_fixed(kind, _EVENT_KIND_DTYPE)], dtype=_EVENT_KIND_DTYPE))
            _put(events["message"], row, np.array([_fixed(message, _EVENT_MESSAGE_DTYPE)],
                                                  dtype=_EVENT_MESSAGE_DTYPE))
            self._f.flush()

    def set_status(self, status: str) -> None:
        if status not in _STATUSES:
            raise ValueError(f"status must be one of {_STATUSES}; got {status!r}")
        with self._disk("the session status"):
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
        if self._closed:  # closed, or stopped by a failed write (the file then reads "interrupted")
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


def _open_swmr_write(path: Path) -> h5py.File:
    """An existing session opened for appending in SWMR-write mode (no non-SWMR write phase)."""
    def attempt(locking: bool) -> h5py.File:
        fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
        fapl.set_libver_bounds(h5py.h5f.LIBVER_V110, h5py.h5f.LIBVER_LATEST)  # the oldest format with SWMR
        if not locking:
            fapl.set_file_locking(False, True)
        fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDWR | h5py.h5f.ACC_SWMR_WRITE, fapl=fapl)
        return h5py.File(fid)
    try:
        return attempt(locking=True)
    except OSError as exc:
        if "unable to lock file" not in str(exc):
            raise SessionError(f"{path}: cannot reopen for writing: {exc}") from None
    # Readers that have the interrupted file open (SWMR readers, a live view, 'vfmlab info' in another
    # terminal) hold HDF5's shared lock; they must not block resume. One writer at a time is kept by
    # the status check (a live writer = "running").
    try:
        return attempt(locking=False)
    except OSError as exc2:
        raise SessionError(f"{path}: cannot reopen for writing: {exc2}") from None


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
