"""vfmlab: the command line and the stages that wire the stage packages together, and their Python front door.

In a notebook or a script::

    import vfmlab

    with vfmlab.open_session("a1.h5") as s:          # the session reader (acquisition.session)
        print(s.specimen, s.n_steps)
    out = vfmlab.identify("a1.h5", model="hgo")       # = vfmlab identify a1.h5 --model hgo
    out.parameters, out.result.flags

Each stage (:func:`identify`, :func:`reconstruct`, :func:`calibrate`, :func:`report`, :func:`export`,
:func:`reprocess`, :func:`run`) takes the session path, an optional frozen settings object
(:class:`IdentifySettings`, ...) and keyword overrides of its fields; the defaults are the command line's.
Everything is imported on first use (PEP 562): ``import vfmlab`` and ``vfmlab --help`` stay fast.
"""

from __future__ import annotations

import sys
import types

_SETTINGS = ("CalibrateSettings", "ExportSettings", "IdentifySettings", "ReconstructSettings", "RegionalSettings",
             "ReportSettings", "ReprocessSettings", "RunSettings", "SelfCalibrationSettings")
#: Public name -> (module, attribute), imported on first use.
_EXPORTS = {
    "open_session": ("acquisition.session", "open_session"),
    "identify": ("vfmlab.stages.identify", "identify"),
    "reconstruct": ("vfmlab.stages.reconstruct", "reconstruct"),
    "calibrate": ("vfmlab.stages.calibrate", "calibrate"),
    "report": ("vfmlab.stages.outputs", "report"),
    "export": ("vfmlab.stages.outputs", "export"),
    "reprocess": ("vfmlab.stages.batch", "reprocess"),
    "run": ("vfmlab.stages.batch", "run"),
    "model_names": ("vfmlab.stages.models", "model_names"),
    "StageError": ("vfmlab.stages.errors", "StageError"),
    "StageFailed": ("vfmlab.stages.errors", "StageFailed"),
    **{name: ("vfmlab.stages.settings", name) for name in _SETTINGS},
}
__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    if name == "__version__":
        # importing importlib.metadata costs tens of milliseconds that ``vfmlab --help`` and ``vfmlab info``
        # need not pay (benchmarks/bench_cli.py)
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("vfmlab")
        except PackageNotFoundError:  # running from a source tree without installation
            value = "0.1.0+source"
    elif name in _EXPORTS:
        import importlib

        module, attribute = _EXPORTS[name]
        value = getattr(importlib.import_module(module), attribute)
    else:
        raise AttributeError(f"module 'vfmlab' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _FrontDoor(types.ModuleType):
    """The ``vfmlab`` module: importing its submodules ``vfmlab.report``, ``vfmlab.export`` or
    ``vfmlab.reprocess`` (the report builder, the ParaView writer, the batch runner) does not replace the
    stage functions of the same names (``from vfmlab.report import build_report`` works as before)."""

    def __setattr__(self, name: str, value) -> None:
        if name in _EXPORTS and isinstance(value, types.ModuleType):
            return  # set by the import system for a submodule; it stays in sys.modules under its full name
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _FrontDoor
