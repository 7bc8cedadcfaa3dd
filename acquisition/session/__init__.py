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
        results/<kind>_NNN  NXprocess: results built with the session (import-markers) or by older versions
    <file>.results/         derived results added later: one file per result + manifest.json (``_store``)

Crash safety: the writer pre-creates every growing dataset, then switches to SWMR mode, and
flushes + fsyncs after every step, so a process killed at any point leaves a file that opens
(``swmr=True``) and holds every completed step. Readers may open it while it is being written.
Derived results never touch the session file: each is its own file, renamed into place and listed
by a manifest replaced atomically and bound to the session's uuid (``_store``); a session built at
once (import) is built under a temporary name and renamed into place (``_staging``).

The package's modules, one concept each: ``_schema`` (version, tables, record types, errors,
validator), ``_writer`` (:class:`SessionWriter`), ``_reader`` (:func:`open_session`,
:class:`Session`), ``_results`` (:func:`write_result`), ``_guards`` (writer liveness, read
faults), ``_opening`` and ``_preflight`` (opening safely), ``_locks`` (waiting locks), ``_store``
(results beside the file), ``_staging`` (all-or-nothing builds) and ``_recovery`` (resume after a kill). Code outside the package imports only the names below (``PREFLIGHT_TIMEOUT`` and
``QUIET_BEFORE_WALK`` are read from ``_preflight`` at each call: re-binding them here changes nothing).
"""

from __future__ import annotations

from acquisition.session._preflight import PREFLIGHT_TIMEOUT, QUIET_BEFORE_WALK, start_preflight
from acquisition.session._reader import Session, incomplete_leftover, open_session
from acquisition.session._results import write_result
from acquisition.session._schema import (
    SCHEMA_VERSION,
    CameraSpec,
    DamagedSessionError,
    SessionError,
    SessionWriteError,
    SpecimenInfo,
    StepRecord,
)
from acquisition.session._staging import StagedSession, import_failure, staged_session
from acquisition.session._store import copy_session, results_dir
from acquisition.session._writer import SessionWriter

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
    "staged_session",
    "StagedSession",
    "import_failure",
    "results_dir",
    "copy_session",
    "incomplete_leftover",
    "PREFLIGHT_TIMEOUT",
    "QUIET_BEFORE_WALK",
]
