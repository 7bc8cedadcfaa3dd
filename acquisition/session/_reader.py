"""Reading a session file: :func:`open_session` and the read-only :class:`Session` view."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.session import _guards, _store
from acquisition.session._guards import _READ_FAULTS, _reads, damaged_error
from acquisition.session._locks import legacy_journal
from acquisition.session._opening import _open_possibly_growing
from acquisition.session._preflight import _preflight
from acquisition.session._schema import (
    _LOG_CHANNELS,
    _STEP_COLUMNS,
    CameraSpec,
    DamagedSessionError,
    SessionError,
    SpecimenInfo,
    _check_result_arrays,
    _decode,
    _read,
    _validate,
)


log = logging.getLogger("acquisition.session")


class Session:
    """A validated, read-only view of a session file. Obtain with :func:`open_session`.

    Every reader raises :class:`DamagedSessionError` (naming the part of the file) when the file
    opened but that part cannot be read; the other parts stay readable.
    """

    def __init__(self, h5file: h5py.File, path: Path):
        self._f = h5file
        self.path = path
        self._entry = h5file["entry"]
        self._raw_size = path.stat().st_size
        self._manifest: _store.Manifest | None = None

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
            if not _guards._writer_alive(pid, host, str(_decode(attrs.get("writer_boot_id", ""))),
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
        """Complete step rows: in every column and with every camera's frame (a writer killed mid-append
        may have left a longer column or an extra frame)."""
        steps = self._entry["steps"]
        images = steps.get("images") or {}
        return int(min([steps[name].shape[0] for name in _STEP_COLUMNS] + [ds.shape[0] for ds in images.values()]))

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
        """Calibration-board frames of ``camera``, shape (n_views, H, W): the views every camera has (complete)."""
        calib = self._entry["calibration/images"]
        return calib[camera][:min(ds.shape[0] for ds in calib.values())]

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
    @property
    @_reads("the session identity (/entry@session_uuid)")
    def uuid(self) -> str:
        """The uuid stored at creation ("" for sessions written before it existed)."""
        return str(_decode(self._entry.attrs.get("session_uuid", "")))

    def _beside(self) -> _store.Manifest:
        """The derived results beside the file that belong to this session (read once)."""
        if self._manifest is None:
            try:
                self._manifest = _store.read_manifest(self.path, self.uuid, self._raw_size)
            except OSError as exc:
                raise damaged_error(self.path, "the list of derived results beside the file", exc) from None
            if self._manifest.note:
                log.warning("%s", self._manifest.note)
        return self._manifest

    @property
    def results_note(self) -> str:
        """One sentence when results beside the file are not shown (another session's, unreadable), else ""."""
        return self._beside().note

    @_reads("the list of derived results (/entry/results)")
    def results_in_file(self) -> list[str]:
        """Names of the result groups stored inside the session file (sessions of older versions)."""
        res = self._entry.get("results")
        return [] if res is None else list(res.keys())

    @_reads("the list of derived results (/entry/results)")
    def results(self, kind: str | None = None) -> list[str]:
        """Names of derived results (e.g. "markers_001"), oldest first, optionally of one kind.

        Results beside the file (``<session>.results/``) and results inside older session files alike.
        """
        res = self._entry.get("results")
        found = [] if res is None else [(str(_decode(res[n].attrs.get("date", ""))), n,
                                         str(_decode(res[n].attrs.get("kind", "")))) for n in res]
        found += [(str(e.get("date", "")), str(e["name"]), str(e.get("kind", ""))) for e in self._beside().entries]
        return [name for _date, name, k in sorted(found) if kind is None or k == kind]

    def result(self, name: str) -> dict[str, Any]:
        """One result: ``{"name", "kind", "arrays": {...}, "parameters": {...}, "attrs": {...}, "units": {...}}``."""
        if name not in self.results():
            raise SessionError(f"{self.path}: no result {name!r}; results are {self.results()}")
        entry = self._beside().entry(name)
        if entry is None:
            return self._result(name)
        return self._result_beside(name, entry)

    @_reads("the result {0!r} (/entry/results/{0})")
    def _result(self, name: str) -> dict[str, Any]:
        return _result_of(name, self._entry["results"][name])

    @_reads("the result {0!r} (beside the file, in <session>.results/{0}.h5)")
    def _result_beside(self, name: str, entry: dict[str, Any]) -> dict[str, Any]:
        with _store.read_result_file(self.path, entry) as f:
            return _result_of(name, f)

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


def _result_of(name: str, g: h5py.Group) -> dict[str, Any]:
    """A result group (inside the session or the root of a result file) as plain data."""
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
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head != b"\x89HDF\r\n\x1a\n":
        raise SessionError(f"{path}: not a session file (not HDF5: the file does not start with the HDF5 signature)")
    _preflight(path)
    try:
        f = _open_possibly_growing(path)
    except SessionError as exc:
        journal = legacy_journal(path)
        if journal is None:
            raise
        raise SessionError(f"{exc}. An older vfmlab left {journal.name} beside it (a result write it never "
                           "finished); this version never applies it: see docs/guide/session-format.md") from None
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
