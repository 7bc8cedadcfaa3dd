"""Derived results: :func:`write_result` adds ``<kind>_NNN`` as its own file beside the session.

The session file is only read. The result is built in memory, written as
``<session>.results/<kind>_NNN.h5`` under a temporary name (every write's length checked), fsynced,
renamed into place and listed in the manifest, itself replaced atomically (see ``_store``).
Results stored inside older session files (``/entry/results``) are still read.
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import logging
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.session import _store
from acquisition.session._locks import LockTimeout
from acquisition.session._reader import open_session
from acquisition.session._schema import SessionError, SessionWriteError, _now_iso, _software_version

log = logging.getLogger("acquisition.session")


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
    """Add a derived result ``<kind>_NNN`` beside the session (never overwrites anything); returns its name.

    Written as ``<session>.results/<kind>_NNN.h5`` and listed in that folder's manifest; the session
    file itself is not touched. A failure (disk full included) leaves everything as it was.

    ``parameters`` (the settings that produced it) is stored as JSON; ``attrs`` values that are
    dicts or lists are stored as JSON in ``<key>_json`` and decoded again by :meth:`Session.result`.
    """
    if not kind.isidentifier():
        raise ValueError(f"kind must be an identifier like 'markers'; got {kind!r}")
    path = Path(path)
    with open_session(path) as session:
        if session.status == "running":
            raise SessionError(f"{path}: the session is still being written; add results once it has finished")
        uuid, in_file = session.uuid, session.results_in_file()
    raw_size = path.stat().st_size
    identity = _store.session_identity(path, uuid)
    image = b""
    try:
        with _store.locked(path) as folder:
            listed = _store.read_manifest(path, uuid, raw_size).names()
            name = _store.next_name(folder, kind, in_file + listed)
            date = _now_iso()
            image = result_image(kind, arrays, parameters, attrs, units, date=date)
            entry = {"name": name, "kind": kind, "file": f"{name}.h5", "date": date, "size": len(image),
                     "sha256": hashlib.sha256(image).hexdigest(), "raw_size": raw_size}
            _store.commit(path, folder, identity, entry, image)
    except LockTimeout as exc:
        raise SessionWriteError(str(exc)) from None
    except _store.ManifestError as exc:  # an unreadable manifest: reported, never replaced
        raise SessionWriteError(f"{exc}; nothing was written. Move it away to start a new list of results") \
            from None
    except OSError as exc:
        exc.needed = len(image) + 4096  # type: ignore[attr-defined]
        raise SessionWriteError(_write_failure(path, exc)) from None
    log.info("wrote result %s beside %s", name, path)
    return name


def result_image(kind: str, arrays: Mapping[str, Any], parameters: Mapping[str, Any],
                 attrs: Mapping[str, Any] | None = None, units: Mapping[str, str] | None = None,
                 date: str = "") -> bytes:
    """The bytes of a result's HDF5 file, built in memory (HDF5 never meets a disk error)."""
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        _fill_result_group(f, kind, arrays, parameters, attrs, units, date)
    return buffer.getvalue()


def write_result_group(f: h5py.File, kind: str, arrays: Mapping[str, Any], parameters: Mapping[str, Any],
                        attrs: Mapping[str, Any] | None, units: Mapping[str, str] | None) -> str:
    """Write a result group inside ``f`` (``/entry/results/<kind>_NNN``): only for a file nobody else sees yet."""
    res = f["entry"].require_group("results")
    existing = [n for n in res if n.startswith(kind + "_")]
    number = 1 + max((int(n.rsplit("_", 1)[1]) for n in existing if n.rsplit("_", 1)[1].isdigit()), default=0)
    name = f"{kind}_{number:03d}"
    _fill_result_group(res.create_group(name), kind, arrays, parameters, attrs, units)
    return name


def _fill_result_group(g: h5py.Group, kind: str, arrays: Mapping[str, Any], parameters: Mapping[str, Any],
                       attrs: Mapping[str, Any] | None, units: Mapping[str, str] | None, date: str = "") -> None:
    g.attrs["NX_class"] = "NXprocess"
    g.attrs["kind"] = kind
    g.attrs["program"] = "vfmlab"
    g.attrs["version"] = _software_version()
    g.attrs["date"] = date or _now_iso()
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
