"""Clear the HDF5 file-consistency flags a killed writer leaves behind (what ``h5clear -s`` does).

A file written with ``libver=("v110", "v110")`` (superblock version 3) records in its superblock
that a writer has it open. If that writer is killed, the flag stays set and HDF5 refuses to
open the file for writing again ("file is already open for write"). Readers can still open
it with ``swmr=True``. To append to it again (resume a session) we reset the flag byte and
rewrite the superblock checksum (Jenkins lookup3, as HDF5's ``H5_checksum_metadata``).

Also :func:`_partial_records`: what a kill left half-appended (resume reports it; the next writes replace it).
"""

from __future__ import annotations

import os

import h5py

from acquisition.session._schema import _LOG_CHANNELS, _STEP_COLUMNS

__all__ = ["clear_consistency_flags", "lookup3"]

_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_MASK = 0xFFFFFFFF


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _MASK


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle`` as used by HDF5 for metadata checksums."""
    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & _MASK
    i = 0
    while length > 12:
        a = (a + int.from_bytes(data[i : i + 4], "little")) & _MASK
        b = (b + int.from_bytes(data[i + 4 : i + 8], "little")) & _MASK
        c = (c + int.from_bytes(data[i + 8 : i + 12], "little")) & _MASK
        # mix(a, b, c)
        a = (a - c) & _MASK; a ^= _rot(c, 4); c = (c + b) & _MASK  # noqa: E702
        b = (b - a) & _MASK; b ^= _rot(a, 6); a = (a + c) & _MASK  # noqa: E702
        c = (c - b) & _MASK; c ^= _rot(b, 8); b = (b + a) & _MASK  # noqa: E702
        a = (a - c) & _MASK; a ^= _rot(c, 16); c = (c + b) & _MASK  # noqa: E702
        b = (b - a) & _MASK; b ^= _rot(a, 19); a = (a + c) & _MASK  # noqa: E702
        c = (c - b) & _MASK; c ^= _rot(b, 4); b = (b + a) & _MASK  # noqa: E702
        i += 12
        length -= 12
    if length == 0:
        return c
    tail = data[i:] + b"\x00" * (12 - length)
    a = (a + int.from_bytes(tail[0:4], "little")) & _MASK
    b = (b + int.from_bytes(tail[4:8], "little")) & _MASK
    c = (c + int.from_bytes(tail[8:12], "little")) & _MASK
    # final(a, b, c)
    c ^= b; c = (c - _rot(b, 14)) & _MASK  # noqa: E702
    a ^= c; a = (a - _rot(c, 11)) & _MASK  # noqa: E702
    b ^= a; b = (b - _rot(a, 25)) & _MASK  # noqa: E702
    c ^= b; c = (c - _rot(b, 16)) & _MASK  # noqa: E702
    a ^= c; a = (a - _rot(c, 4)) & _MASK  # noqa: E702
    b ^= a; b = (b - _rot(a, 14)) & _MASK  # noqa: E702
    c ^= b; c = (c - _rot(b, 24)) & _MASK  # noqa: E702
    return c


def clear_consistency_flags(path: str | os.PathLike) -> bool:
    """Reset the superblock's file-consistency flags of ``path`` in place.

    Returns True if flags were set and have been cleared, False if they were already clear.
    Raises ValueError if the file is not HDF5 with a version 2/3 superblock at offset 0,
    or if its stored checksum does not match (the file is then left untouched).
    """
    with open(path, "r+b") as fh:
        head = fh.read(64)
        if not head.startswith(_SIGNATURE):
            raise ValueError(f"{os.fspath(path)!r} has no HDF5 signature at offset 0")
        version = head[8]
        if version not in (2, 3):
            raise ValueError(f"{os.fspath(path)!r}: superblock version {version}; expected 2 or 3")
        size_of_offsets = head[9]
        end = 12 + 4 * size_of_offsets
        stored = int.from_bytes(head[end : end + 4], "little")
        if lookup3(head[:end]) != stored:
            raise ValueError(f"{os.fspath(path)!r}: superblock checksum mismatch; not modifying it")
        if head[11] == 0:
            return False
        block = bytearray(head[:end])
        block[11] = 0
        fh.seek(0)
        fh.write(bytes(block) + lookup3(bytes(block)).to_bytes(4, "little"))
        fh.flush()
        os.fsync(fh.fileno())
    return True


def _partial_records(entry: h5py.Group) -> list[str]:
    """The records a killed writer left half-appended (nothing is changed: the next writes replace them).

    Log and event columns are appended one after another, and a step's frames are written before
    its table row, so after a kill the datasets of one table can differ in length by one append.
    Readers count only complete rows (the shortest column); the writer writes its next record at that
    index, over the leftovers, so resume needs no write of its own to cut them back.
    """
    tables = [list(entry["log"][channel].values()) for channel in _LOG_CHANNELS] + [list(entry["events"].values())]
    calib = entry["calibration/images"] if "calibration/images" in entry else {}
    tables.append(list(calib.values()))
    steps = entry["steps"]
    tables.append([steps[name] for name in _STEP_COLUMNS] + list(steps["images"].values()))
    partial = []
    for datasets in tables:
        n = min((ds.shape[0] for ds in datasets), default=0)
        partial += [f"{ds.name}[{n}:{ds.shape[0]}]" for ds in datasets if ds.shape[0] > n]
    return partial


# -- reading ---------------------------------------------------------------------------------
