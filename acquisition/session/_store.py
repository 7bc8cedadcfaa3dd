"""Derived results beside the session: one small file per result, found by an atomically replaced manifest.

Layout, for a session ``S.h5``::

    S.h5.results/
        manifest.json               {"format", "session": {"uuid", "fingerprint"}, "results": [...]}
        identification_003.h5       one result: its attributes on the root group, its arrays as datasets
        .lock                       advisory lock that serialises writers (readers never take it)

Nothing is rewritten in place. A result is built in memory, written under a temporary name with
every write's length checked, fsynced and renamed into place; then the manifest is written the same
way (temporary name, fsync, rename, fsync of the folder). The rename of the manifest is the commit
point: before it the new result is an unlisted file that readers ignore, after it the result is
there. A kill, a full disk or a short write at any point therefore leaves the previous manifest and
every listed file intact; the session file itself is only ever read.

The manifest is bound to the session it belongs to: ``session.uuid`` is the uuid stored in the
session at creation (``/entry@session_uuid``); sessions written before it existed are identified by
their ``fingerprint`` (size and SHA-256 of the first and last 64 KiB). Each entry also records the
size of the raw session it was derived from (``raw_size``) and the size and SHA-256 of its own file,
which readers verify before HDF5 sees a byte of it. A manifest of another session (a file copied
onto the name, a session re-imported under it) is never applied: readers ignore it and say so.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py

from acquisition.session._locks import wait_lock

log = logging.getLogger("acquisition.session")

FORMAT = "vfmlab-results-1"
MANIFEST = "manifest.json"
_NAME = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)_(\d+)(\.h5)?$")
_EDGE = 65536


class ManifestError(ValueError):
    """A results manifest that cannot be read: reported, never replaced (it lists results)."""


def results_dir(path: str | os.PathLike) -> Path:
    """``<session>.results``: the folder that holds the session's derived results."""
    path = Path(path)
    return path.with_name(path.name + ".results")


# ------------------------------------------------------------------------ the one place that touches the disk
def _io(op: str, target: Any, data: bytes = b"") -> None:
    """One disk operation of a result write (tests patch this to kill or fill the disk at every write).

    ``op`` is "write" (``target`` an fd; the whole of ``data`` is written, short writes continued and a
    write that makes no progress is an error), "fsync" (fd), "rename" ((src, dst)) or "fsync_dir" (folder).
    """
    if op == "write":
        view = memoryview(data)
        while view:
            n = os.write(target, view)
            if n <= 0:
                raise OSError(28, "No space left on device (a write made no progress)")
            view = view[n:]
    elif op == "fsync":
        os.fsync(target)
    elif op == "rename":
        os.rename(*target)
    elif op == "fsync_dir":
        fd = os.open(target, os.O_RDONLY)
        try:
            os.fsync(fd)
        except OSError:  # pragma: no cover - a file system that refuses directory fsync
            pass
        finally:
            os.close(fd)


def _put(path: Path, data: bytes) -> None:
    """``data`` at ``path``, atomically: temporary name, every write's length checked, fsync, rename.

    The caller fsyncs the folder (``_io("fsync_dir", ...)``) to make the rename durable.
    """
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        try:
            _io("write", fd, data)
            _io("fsync", fd)
        finally:
            os.close(fd)
        written = os.stat(tmp).st_size
        if written != len(data):
            raise OSError(28, f"{tmp}: {written} of {len(data)} bytes written")
        _io("rename", (tmp, path))
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


# ------------------------------------------------------------------------ identity
def session_identity(path: Path, uuid: str) -> dict[str, str]:
    """What binds a manifest to its session: the stored uuid, or for older sessions the fingerprint."""
    if uuid:
        return {"uuid": uuid}
    return {"uuid": "", "fingerprint": fingerprint(path)}


def fingerprint(path: Path) -> str:
    """``size:<bytes>:<sha256 of the first and last 64 KiB>`` of a session written before uuids."""
    size = os.stat(path).st_size
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read(_EDGE))
        fh.seek(max(0, size - _EDGE))
        h.update(fh.read(_EDGE))
    return f"size:{size}:{h.hexdigest()}"


# ------------------------------------------------------------------------ reading
class Manifest:
    """The manifest of a results folder as read: the entries bound to this session, and why others are not."""

    def __init__(self, entries: list[dict[str, Any]], note: str = ""):
        self.entries = entries
        #: One sentence when results beside the file are not shown (another session's, unreadable).
        self.note = note

    def names(self) -> list[str]:
        return [e["name"] for e in self.entries]

    def entry(self, name: str) -> dict[str, Any] | None:
        return next((e for e in self.entries if e["name"] == name), None)


def _load_raw(folder: Path) -> dict[str, Any] | None:
    """The manifest's JSON, or None when there is none; ValueError when it is not a vfmlab manifest."""
    try:
        text = (folder / MANIFEST).read_bytes()
    except FileNotFoundError:
        return None
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise ManifestError(f"{folder / MANIFEST}: the results manifest is damaged ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("results"), list):
        raise ManifestError(f"{folder / MANIFEST}: not a vfmlab results manifest")
    return data


def _bound(data: dict[str, Any], identity: dict[str, str]) -> bool:
    stored = data.get("session") or {}
    if identity.get("uuid"):
        return stored.get("uuid") == identity["uuid"]
    return not stored.get("uuid") and stored.get("fingerprint") == identity.get("fingerprint")


def read_manifest(path: Path, uuid: str, raw_size: int) -> Manifest:
    """The derived results beside ``path`` that belong to this session (uuid ``uuid``, ``raw_size`` bytes)."""
    folder = results_dir(path)
    if not folder.is_dir():
        return Manifest([])
    try:
        data = _load_raw(folder)
    except (OSError, ManifestError) as exc:
        return Manifest([], f"{exc}; its results are not shown")
    if data is None:
        return Manifest([])
    identity = session_identity(path, uuid) if uuid else {"uuid": "", "fingerprint": fingerprint(path)}
    if not _bound(data, identity):
        return Manifest([], f"{folder} holds the results of another session (not of this file); they are "
                            "not shown. Move that folder away, or put the session it belongs to back")
    entries = [e for e in data["results"] if isinstance(e, dict) and int(e.get("raw_size", 0)) <= raw_size]
    hidden = len(data["results"]) - len(entries)
    note = (f"{folder}: {hidden} result(s) derived from a longer version of this session are not shown"
            if hidden else "")
    return Manifest(entries, note)


def read_result_file(path: Path, entry: dict[str, Any]) -> h5py.File:
    """The result's HDF5 file, verified against the manifest (size and SHA-256) and opened from memory."""
    file = results_dir(path) / entry["file"]
    data = file.read_bytes()
    if len(data) != int(entry["size"]) or hashlib.sha256(data).hexdigest() != entry["sha256"]:
        raise OSError(f"{file}: {len(data)} bytes whose checksum does not match the manifest")
    return h5py.File(io.BytesIO(data), "r")


# ------------------------------------------------------------------------ writing
@contextlib.contextmanager
def locked(path: Path, timeout: float | None = None) -> Iterator[Path]:
    """The results folder of ``path``, created if need be, held under its writers' lock."""
    folder = results_dir(path)
    created = not folder.is_dir()
    if created:
        folder.mkdir(exist_ok=True)
    fd = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        wait_lock(fd, folder, exclusive=True, timeout=timeout)
        yield folder
    finally:
        if created and not (folder / MANIFEST).exists():  # nothing committed: leave no trace
            with contextlib.suppress(OSError):
                (folder / ".lock").unlink()
                folder.rmdir()
        os.close(fd)


def next_name(folder: Path, kind: str, taken: list[str]) -> str:
    """``<kind>_NNN`` one past every number used by ``taken`` names and by the files in ``folder``."""
    names = list(taken) + [n.lstrip(".").split(".tmp-")[0] for n in os.listdir(folder)]
    numbers = [int(m.group(2)) for m in map(_NAME.match, names) if m and m.group(1) == kind]
    return f"{kind}_{1 + max(numbers, default=0):03d}"


def commit(path: Path, folder: Path, identity: dict[str, str], entry: dict[str, Any], image: bytes) -> None:
    """Write the result file, then the manifest that lists it (the commit point). Caller holds the lock."""
    data = _load_raw(folder)  # an unreadable manifest is reported, never replaced (it lists results)
    if data is not None and not _bound(data, identity):
        stored = data.get("session") or {}
        aside = folder / f"manifest-of-{stored.get('uuid') or 'an-older-session'}.json"
        log.warning("%s held the results of another session; its manifest is kept as %s", folder, aside.name)
        _io("rename", (folder / MANIFEST, aside))
        data = None
    entries = list(data["results"]) if data else []
    target = folder / entry["file"]
    _put(target, image)
    _io("fsync_dir", folder)
    manifest = {"format": FORMAT, "session": identity, "results": entries + [entry]}
    try:
        _put(folder / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True).encode())
    except BaseException:
        with contextlib.suppress(OSError):  # never listed: remove it so the folder is as it was
            target.unlink()
        raise
    _io("fsync_dir", folder)
    _io("fsync_dir", folder.parent)  # the folder itself, when this write created it


def copy_session(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """Copy a session file together with its derived results (``<src>.results`` -> ``<dst>.results``).

    ``dst`` must not exist, nor its results folder. Returns ``dst``.
    """
    import shutil

    src, dst = Path(src), Path(dst)
    if dst.exists() or results_dir(dst).exists():
        raise FileExistsError(f"{dst}: exists; copy_session never overwrites")
    shutil.copyfile(src, dst)
    if results_dir(src).is_dir():
        shutil.copytree(results_dir(src), results_dir(dst), ignore=shutil.ignore_patterns(".lock", ".*.tmp-*"))
    return dst
