"""Start-up of a command that loads the numerical stack: the cyclic garbage collector kept off the loaded modules.

Loading numpy, h5py, scipy and the stage packages leaves ~92 000 objects tracked by the collector
(functions, classes, dicts), none of them garbage. CPython's collector scans them again and again while
they load (the young ones every 700 allocations, all of them once at the end): ~35 ms of the ~0.6 s of CPU of
``vfmlab identify --uncertainty gauss-newton`` (benchmarks/bench_cli.py; ``gc.callbacks`` timing).
:func:`modules_loading` pauses the collector while a command imports, then freezes what is loaded
(``gc.freeze``: moved to the permanent generation, never scanned again; the CPython documentation's
recipe before ``fork``, which :func:`vfmlab.parallel.fork_map` does) and unfreezes it when the command
ends, so a caller that runs commands in-process (the tests) keeps an ordinary collector.

When the command is the process's own command line (:func:`vfmlab.cli.main` called without
arguments: the console script, ``python -m vfmlab``), the process ends right after it, and the loaded
modules stay frozen: CPython's final collections at exit would otherwise scan all of them again
(~0.1 s of CPU after scipy is loaded, at load 4; a fresh interpreter importing the same modules then
exiting: 463 ms of CPU, 364 ms with them frozen, 361 ms with ``os._exit``). What the command itself
allocates is still collected at exit as usual (open files are closed by their ``with`` blocks anyway).
Garbage collection only reclaims memory: no result depends on it.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Callable, Iterator

__all__ = ["modules_loading", "process_ends_after_command"]

_process_ends = False


def process_ends_after_command() -> None:
    """Say that this process ends when its command does (:func:`vfmlab.cli.main` on ``sys.argv``): what
    :func:`modules_loading` froze stays frozen to the end."""
    global _process_ends
    _process_ends = True


@contextlib.contextmanager
def modules_loading() -> Iterator[Callable[[], None]]:
    """Pause the cyclic garbage collector until the yielded ``loaded()`` is called (or the block ends).

    ``loaded()`` freezes the objects that exist then (the loaded modules) and restores the collector;
    they are unfrozen when the ``with`` block ends, unless the process ends after the command
    (:func:`process_ends_after_command`). Where the caller had frozen objects already
    (``gc.get_freeze_count() > 0``) nothing is frozen or unfrozen, only paused. Usage::

        with modules_loading() as loaded:
            import scipy.optimize  # ... the command's imports
            loaded()
            ...  # the command's work, with the collector on
    """
    was_enabled = gc.isenabled()
    ours = gc.get_freeze_count() == 0
    state = {"paused": True, "frozen": False}

    def loaded() -> None:
        if not state["paused"]:
            return
        if ours:
            gc.freeze()
            state["frozen"] = True
        if was_enabled:
            gc.enable()
        state["paused"] = False

    gc.disable()
    try:
        yield loaded
    finally:
        if state["paused"] and was_enabled:
            gc.enable()
        if state["frozen"] and not _process_ends:
            gc.unfreeze()
