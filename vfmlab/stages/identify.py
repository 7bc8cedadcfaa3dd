"""The identify stage: constitutive parameters from a session's marker tracks (Virtual Fields Method), stored as
an "identification" result, or along the axis as a "regional" result (``regions``).

The work is :func:`vfmlab.pipeline.identify_stored` and :func:`vfmlab.regional.identify_regional_stored`; this
module turns the settings of ``vfmlab identify`` into their arguments and the outcome into the command's JSON.
Parameters in SI (Pa, rad), the unit of each in ``units``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import ProgressFactory, no_progress
from vfmlab.stages.settings import IdentifySettings, RegionalSettings, settings_with

__all__ = ["IdentifyOutcome", "RegionalOutcome", "identify", "si_unit", "parse_smooth", "regional", "verdict_lines"]


def verdict_lines(verdict: str | None, reasons=(), parameter_verdicts=None, parameter_reasons=None) -> list[str]:
    """The verdict of an identification as lines to show: "verdict: trusted|doubtful", then each doubtful
    parameter's reason (names sharing one reason on one line), then the other reasons; [] when not judged
    (results stored before verdicts)."""
    if not verdict:
        return []
    by_reason: dict[str, list[str]] = {}
    for name, reason in (parameter_reasons or {}).items():
        if (parameter_verdicts or {}).get(name) == "doubtful" and reason:
            by_reason.setdefault(reason, []).append(name)
    return ([f"verdict: {verdict}"] + [f"  {', '.join(names)} doubtful: {reason}" for reason, names in by_reason.items()]
            + [f"  - {reason}" for reason in reasons if reason not in by_reason])


def parse_smooth(text: str | tuple[int, int] | None):
    """``--smooth`` text -> "auto", None ("none") or (axial degree, harmonics); a pair of ints and None (no
    smoothing) pass through."""
    if text is None or isinstance(text, (tuple, list)):
        return None if text is None else tuple(text)
    if text.strip().lower() == "auto":
        return "auto"
    if text.strip().lower() == "none":
        return None
    try:
        smoothing = tuple(int(v) for v in text.split(","))
        if len(smoothing) != 2 or min(smoothing) < 0:
            raise ValueError
    except ValueError:
        raise StageError(f"--smooth must be 'auto', 'none' or two non-negative integers AXIAL,HARMONICS like 4,2; "
                         f"got {text!r}") from None
    return smoothing


def si_unit(model: str, name: str) -> str:
    """The SI unit of parameter ``name`` of ``model`` ("Pa", "rad", "1")."""
    from identification import get_model

    m = get_model(model)
    return m.units[m.parameter_names.index(name)]


@dataclass(frozen=True)
class IdentifyOutcome:
    """An identification stored in a session: ``group`` (e.g. "identification_003"), ``result``
    (``identification.IdentificationResult``: ``parameters``, ``stderr``, ``uncertainty``, ``flags``, ...) and
    ``data`` (the inputs used, with ``settings`` and ``notes``)."""

    group: str
    result: Any
    data: dict[str, Any]
    settings: IdentifySettings

    @property
    def parameters(self) -> dict[str, float]:
        """Identified parameters, SI."""
        return dict(self.result.parameters)

    @property
    def units(self) -> dict[str, str]:
        """SI unit of each parameter."""
        return {n: si_unit(self.settings.model, n) for n in self.result.parameters}

    def to_dict(self) -> dict[str, Any]:
        """What ``vfmlab identify --json`` prints (SI)."""
        r, settings = self.result, self.data.get("settings", {})
        return {"model": self.settings.model, "wall": settings.get("wall", self.settings.wall),
                "ends": settings.get("ends"),
                "ends_source": settings.get("ends_source"), "parameters": r.parameters, "stderr": r.stderr,
                "interval_95": (None if r.uncertainty is None else {k: list(v) for k, v in r.uncertainty.interval.items()}),
                "units": self.units, "cost": r.cost, "converged": r.converged, "flags": list(r.flags),
                "verdict": r.verdict, "verdict_reasons": list(r.verdict_reasons),
                "parameter_verdicts": dict(r.parameter_verdicts), "parameter_reasons": dict(r.parameter_reasons),
                "hypotheses": [{**h, "parameters": dict(h["parameters"])} for h in r.hypotheses],
                "result_group": self.group}

    @property
    def wall(self) -> str:
        """The wall form used (stated, or chosen by the data)."""
        return str(self.data.get("settings", {}).get("wall", self.settings.wall))


@dataclass(frozen=True)
class RegionalOutcome:
    """A regional identification stored in a session: ``group``, ``result`` (``profiles``, ``stderr``,
    ``differs``, ...), ``data`` (with ``choice`` for ``regions="auto"``) and the SI ``units`` of the parameters."""

    group: str
    result: Any
    data: dict[str, Any]
    units: dict[str, str]

    def to_dict(self) -> dict[str, Any]:
        """What ``vfmlab identify --regions ... --json`` prints (SI)."""
        result, choice = self.result, self.data.get("choice")
        lists = lambda d: {n: v.tolist() for n, v in d.items()}  # noqa: E731
        return {
            "model": result.model, "regional": list(result.regional), "profile_kind": result.kind,
            "band_edges_m": result.edges.tolist(), "band_centres_m": result.centres.tolist(),
            "profiles": lists(result.profiles), "stderr": lists(result.stderr), "interval_95": lists(result.interval),
            "uncertainty": result.uncertainty, "z_score": lists(result.z_score),
            "differs": result.differs.tolist(), "parameters": result.parameters,
            "parameter_stderr": result.parameter_stderr,
            "homogeneous": result.homogeneous.parameters, "units": self.units, "cost": result.cost,
            "auto": None if choice is None else {"n_bands": choice.n_bands, "candidates": choice.candidates.tolist(),
                                                 "chi2": choice.chi2.tolist(), "criterion": choice.criterion.tolist()},
            "converged": result.converged, "flags": list(result.flags), "result_group": self.group}


def identify(session_path: str | os.PathLike, settings: IdentifySettings | None = None, *,
             invoked_by: str = "python", progress: ProgressFactory = no_progress,
             **overrides: Any) -> IdentifyOutcome | RegionalOutcome:
    """Identify ``settings.model`` from the latest marker tracks of the session and store the result in it.

    ``vfmlab.identify("a1.h5", model="hgo")`` is ``vfmlab identify a1.h5 --model hgo``; the defaults are the
    command's (:class:`IdentifySettings`). With ``regions`` set, a :class:`RegionalOutcome`. ``progress`` shows
    the fits and the bootstrap (:mod:`vfmlab.stages.feedback`). Raises ``StageError`` (bad input) or ``StageFailed``.
    """
    from vfmlab.pipeline import identify_stored

    s = settings_with(IdentifySettings, settings, overrides)
    smoothing = parse_smooth(s.smooth)
    if s.regions is not None:
        return regional(session_path, RegionalSettings(regions=s.regions, model=s.model, wall=s.wall, ends=s.ends,
                                                       smooth=s.smooth, uncertainty=s.uncertainty),
                        invoked_by=invoked_by, progress=progress)
    with progress(f"identify {s.model}", None) as update:
        group, result, data = identify_stored(session_path, model=s.model, wall=s.wall, ends=s.ends,
                                              optimizer=s.optimizer, smoothing=smoothing, uncertainty=s.uncertainty,
                                              weighting=s.weighting, invoked_by=invoked_by,
                                              progress=_told(update, f"identify {s.model}"))
    return IdentifyOutcome(group, result, data, s)


def _told(update, prefix: str):
    """A core's ``progress(done, total, what)`` drawn by a stage's progress ``update``."""
    return lambda done, total, what: update(done, total, f"{prefix}: {what}")


def regional(session_path: str | os.PathLike, settings: RegionalSettings | None = None, *,
             invoked_by: str = "python", progress: ProgressFactory = no_progress, **overrides: Any) -> RegionalOutcome:
    """Identify the stress-like parameter along the axis (``vfmlab identify --regions``) and store a "regional"
    result. A malformed ``regions`` is a StageError; a failed identification a StageFailed."""
    from identification import get_model
    from vfmlab.regional import identify_regional_stored, parse_regions

    s = settings_with(RegionalSettings, settings, overrides)
    try:
        spec = parse_regions(s.regions)
    except ValueError as exc:
        raise StageError(str(exc)) from None
    try:
        with progress(f"identify {s.model} --regions {spec}", None) as update:
            group, result, data = identify_regional_stored(session_path, regions=spec, model=s.model, wall=s.wall,
                                                           ends=s.ends, smoothing=parse_smooth(s.smooth),
                                                           uncertainty=s.uncertainty, invoked_by=invoked_by,
                                                           progress=_told(update, f"regional {s.model}"))
    except StageError as exc:
        raise StageFailed(str(exc)) from None
    m = get_model(s.model)
    return RegionalOutcome(group, result, data, dict(zip(m.parameter_names, m.units)))
