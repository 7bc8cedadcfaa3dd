"""The pre-flight check of the rig (``vfmlab check-rig``: :mod:`vfmlab.stages.check`; the start of ``vfmlab run``).

A frame from every camera, its markers detected (:func:`reconstruction.detect_markers`) and measured
(:func:`reconstruction.image_quality`: count, sharpness, saturation, marker contrast), the markers seen by
two or more cameras when the rig has a calibration (:func:`reconstruction.markers_in_views`), a few
seconds of every instrument (zero offset, noise, drift), the stage's state; one verdict line per device,
in words. The judging functions are pure (:func:`judge_camera`, :func:`judge_channel`); :func:`check_bench`
reads an open :class:`vfmlab.bench.Bench`; :func:`save_check` and :func:`store_check` keep the record (PNG
images with their detections, or a ``rig_check`` result in the session).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vfmlab.stages.settings import CheckLimits

__all__ = ["DeviceVerdict", "RigCheck", "check_bench", "check_images", "judge_camera", "judge_channel",
           "judge_stage", "keep_check", "preflight", "rig_calibration", "save_check", "store_check"]

log = logging.getLogger(__name__)

MMHG = 133.322387415
#: verdict words, mildest first
VERDICTS = ("OK", "CHECK", "FAULT")


@dataclass(frozen=True)
class DeviceVerdict:
    """One device's verdict: ``verdict`` in VERDICTS, ``line`` the sentence for the operator, ``metrics`` SI."""

    device: str
    verdict: str
    line: str
    metrics: dict[str, Any] = field(default_factory=dict)


@dataclass
class RigCheck:
    """What the check found: one verdict per device, the multi-view line, the images and their detections."""

    devices: list[DeviceVerdict]
    views_line: str
    images: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    centres: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    diameters: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def passed(self) -> bool:
        """No device at FAULT."""
        return all(d.verdict != "FAULT" for d in self.devices)

    def verdict(self, device: str) -> str:
        return next(d.verdict for d in self.devices if d.device == device)

    def lines(self) -> list[str]:
        return [d.line for d in self.devices] + [self.views_line]

    def to_dict(self) -> dict[str, Any]:
        return {"passed": self.passed, "views": self.views_line,
                "devices": [{"device": d.device, "verdict": d.verdict, "line": d.line, "metrics": d.metrics}
                            for d in self.devices]}


def _line(device: str, problems: list[tuple[str, str]], facts: str) -> DeviceVerdict:
    """A verdict from ``problems`` [(verdict, reason)] and the measured ``facts``."""
    worst = max((VERDICTS.index(v) for v, _ in problems), default=0)
    word = VERDICTS[worst]
    reasons = "; ".join(r for _, r in problems)
    return DeviceVerdict(device, word, f"{device}: {word} - " + (f"{reasons} ({facts})" if reasons else facts))


def judge_camera(name: str, quality: Any, matched: int | None, limits: CheckLimits = CheckLimits()) -> DeviceVerdict:
    """Verdict of camera ``name`` from its :class:`reconstruction.ImageQuality` and the number of its markers
    seen by another camera (None: no calibration)."""
    q, lim = quality, limits
    problems = []
    if q.n_markers < lim.min_markers:
        problems.append(("FAULT", f"sees {q.n_markers} markers, needs {lim.min_markers}: is the specimen in view, "
                                  "lit and marked?"))
    if q.saturated_fraction > lim.max_saturated:
        problems.append(("FAULT", f"{100 * q.saturated_fraction:.1f} % of pixels saturated (at most "
                                  f"{100 * lim.max_saturated:g} %): lower exposure, gain or light, or move a reflection"))
    if q.sharpness < lim.min_sharpness:
        problems.append(("FAULT", f"blurred: sharpness {q.sharpness:.3f} (needs {lim.min_sharpness:g}): focus the lens"))
    if q.n_markers and q.contrast < lim.min_contrast:
        problems.append(("FAULT", f"markers faint: contrast {q.contrast:.2f} (needs {lim.min_contrast:g}): focus, "
                                  "exposure or lighting"))
    if matched is not None and q.n_markers >= lim.min_markers and matched < lim.min_matched:
        problems.append(("CHECK", f"only {matched} of its markers seen by another camera: check its aim and the "
                                  "calibration"))
    facts = (f"{q.n_markers} markers, sharpness {q.sharpness:.3f}, edge width {q.edge_width_px:.1f} px, "
             f"contrast {q.contrast:.2f}, {100 * q.saturated_fraction:.2f} % saturated"
             + ("" if matched is None else f", {matched} seen by another camera"))
    v = _line(f"camera {name}", problems, facts)
    return DeviceVerdict(v.device, v.verdict, v.line, {**q.to_dict(), "matched": matched})


def judge_channel(role: str, t: np.ndarray, value: np.ndarray, limits: CheckLimits = CheckLimits()) -> DeviceVerdict:
    """Verdict of an instrument from its readings ``value`` (n,) (Pa for "pressure", N for "force") at times
    ``t`` (n,) s: zero offset (mean), noise (standard deviation about a line) and drift (the line's slope,
    counted only when it exceeds three standard errors)."""
    pressure = role == "pressure"
    name = "pressure" if pressure else "load cell"
    t, value = np.asarray(t, float), np.asarray(value, float)
    ok = np.isfinite(t) & np.isfinite(value)
    t, value = t[ok], value[ok]
    if t.size < 10 or np.ptp(t) <= 0:
        return DeviceVerdict(name, "FAULT", f"{name}: FAULT - {t.size} readings in the check: is it connected "
                                            "and answering?", {"n": int(t.size)})
    A = np.stack([np.ones_like(t), t - t.mean()], 1)
    coef, *_ = np.linalg.lstsq(A, value, rcond=None)
    resid = value - A @ coef
    noise = float(resid.std(ddof=2)) if t.size > 2 else 0.0
    slope, offset = float(coef[1]), float(value.mean())
    se = noise / math.sqrt(float(np.sum((t - t.mean()) ** 2)))
    lim_off, lim_noise, lim_drift = ((limits.max_pressure_offset_pa, limits.max_pressure_noise_pa,
                                      limits.max_pressure_drift_pa_per_s) if pressure else
                                     (limits.max_force_offset_n, limits.max_force_noise_n, limits.max_force_drift_n_per_s))
    scale, unit = (MMHG, "mmHg") if pressure else (1.0, "N")
    fmt = ".2f" if pressure else ".4f"
    problems = []
    if abs(slope) > lim_drift and abs(slope) > 3 * se:
        problems.append(("FAULT", f"drifting {60 * slope / scale:+{fmt}} {unit}/min (at most {60 * lim_drift / scale:{fmt}}):"
                                  " let it warm up, check its cable and mounting, re-zero"))
    if noise > lim_noise:
        problems.append(("FAULT", f"noisy: {noise / scale:{fmt}} {unit} RMS (at most {lim_noise / scale:{fmt}}): check "
                                  "the cable, grounding and pump vibration"))
    if abs(offset) > lim_off:
        problems.append(("CHECK", f"zero offset {offset / scale:+{fmt}} {unit} (at most {lim_off / scale:{fmt}}): "
                                  + ("vent and re-zero" if pressure else "tare it unloaded, or is the specimen preloaded?")))
    facts = (f"offset {offset / scale:+{fmt}} {unit}, noise {noise / scale:{fmt}} {unit} RMS, drift "
             f"{60 * slope / scale:+{fmt}} {unit}/min over {np.ptp(t):.1f} s, {t.size} readings")
    v = _line(name, problems, facts)
    return DeviceVerdict(v.device, v.verdict, v.line, {"offset": offset, "noise": noise, "drift_per_s": slope,
                                                       "n": int(t.size), "unit": "Pa" if pressure else "N"})


def judge_stage(motor: Any, config: Any) -> DeviceVerdict:
    """Verdict of the motorised stage (a :class:`acquisition.ZaberStage`) against the rig file's ``[stage]``;
    nothing moves."""
    from acquisition import InstrumentError

    try:
        x = motor.position()
        homed = motor.homed
    except InstrumentError as exc:
        return DeviceVerdict("stage", "FAULT", f"stage: FAULT - {type(exc).__name__}: {exc} (clear it, or check "
                                               "the carriage and the cable)")
    problems = []
    if homed is False:
        problems.append(("CHECK", "not homed: 'vfmlab run' homes it (after asking) before the test"))
    elif not config.min_m <= x <= config.max_m:
        problems.append(("CHECK", f"at {x * 1e3:.3f} mm, outside the soft limits"))
    facts = (f"at {x * 1e3:.3f} mm, stretch 1 at x0 = {config.x0_m * 1e3:.3f} mm, soft limits "
             f"{config.min_m * 1e3:g}..{config.max_m * 1e3:g} mm")
    v = _line("stage", problems, facts)
    return DeviceVerdict(v.device, v.verdict, v.line, {"position_m": x, "homed": homed})


def check_images(images: dict[str, np.ndarray], cameras: list | None, views_reason: str,
                 limits: CheckLimits = CheckLimits()) -> RigCheck:
    """Detect, measure and judge one image per camera (``images``: name -> (H, W)); ``cameras``: the rig's
    calibration in the same order (None: the multi-view line says ``views_reason``)."""
    from reconstruction import detect_markers, image_quality, markers_in_views

    names = list(images)
    dets = {n: detect_markers(images[n]) for n in names}
    matched: list[int | None] = [None] * len(names)
    if cameras is not None:
        n_points, per_camera = markers_in_views([dets[n].centres for n in names], cameras)
        matched = [int(k) for k in per_camera]
        views = f"markers seen by two or more cameras: {n_points} ({views_reason})"
    else:
        views = f"markers seen by two or more cameras: not checked ({views_reason})"
    devices = [judge_camera(n, image_quality(images[n], dets[n]), m, limits) for n, m in zip(names, matched)]
    return RigCheck(devices, views, dict(images), {n: d.centres for n, d in dets.items()},
                    {n: d.diameter for n, d in dets.items()})


def check_bench(bench: Any, *, seconds: float = 3.0, limits: CheckLimits = CheckLimits(),
                calibration: tuple[list | None, str] = (None, "the rig file names no calibration"),
                sleep: Callable[[float], None] = time.sleep, clock: Callable[[], float] = time.monotonic) -> RigCheck:
    """The check of an open bench: one frame per camera, ``seconds`` of readings, the stage; nothing moves."""
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0 s; got {seconds}")
    t0 = clock()
    images = {cam.name: cam.grab(5.0).pixels for cam in bench.cameras}
    result = check_images(images, calibration[0], calibration[1], limits)
    sleep(max(0.0, seconds - (clock() - t0)))
    for role in ("pressure", "force"):
        rec = bench.sampler.history(role, seconds)
        result.devices.append(judge_channel(role, rec.t_monotonic, rec.value, limits))
    if getattr(bench, "motor", None) is not None:
        result.devices.append(judge_stage(bench.motor, bench.config.stage))
    return result


def overlay(image: np.ndarray, centres: np.ndarray, diameters: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR copy of ``image`` with a green circle around every detected marker."""
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8:
        top = float(np.iinfo(img.dtype).max) if np.issubdtype(img.dtype, np.integer) else float(np.nanmax(img) or 1)
        img = np.clip(img.astype(np.float64) * (255.0 / top), 0, 255).astype(np.uint8)
    out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    for (x, y), d in zip(np.asarray(centres).reshape(-1, 2), np.asarray(diameters).reshape(-1)):
        r = int(round(d / 2 + 2)) if np.isfinite(d) else 4
        cv2.circle(out, (int(round(x)), int(round(y))), r, (0, 200, 0), 1, cv2.LINE_AA)
    return out


def save_check(check: RigCheck, folder: str | Path) -> list[Path]:
    """Write ``<camera>.png`` (the image with its detections) and ``check.json`` into ``folder``."""
    import cv2

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, image in check.images.items():
        path = folder / f"{name}.png"
        if not cv2.imwrite(str(path), overlay(image, check.centres[name], check.diameters[name])):
            raise OSError(f"cannot write {path}")
        written.append(path)
    path = folder / "check.json"
    path.write_text(json.dumps(check.to_dict(), indent=2, default=float) + "\n")
    return [*written, path]


def store_check(check: RigCheck, session: str | Path) -> str:
    """Store the check as a ``rig_check`` result of the (finished) session: images, centres and the verdicts."""
    from acquisition.session import write_result

    arrays: dict[str, Any] = {}
    units = {}
    for name in check.images:
        arrays[f"image_{name}"] = check.images[name]
        arrays[f"centres_{name}"] = np.asarray(check.centres[name], float).reshape(-1, 2)
        units[f"centres_{name}"] = "px"
    attrs = {"passed": check.passed, "lines": check.lines(), "devices": check.to_dict()["devices"]}
    return write_result(session, "rig_check", arrays, {"views": check.views_line}, attrs=attrs, units=units)


def rig_calibration(rig: Any, bench: Any) -> tuple[list | None, str]:
    """The cameras to match markers across views with, ordered as ``bench.cameras``, and where they come from
    (or None and why not): the rig file's ``[rig] calibration``, else the simulated rig's exact cameras."""
    names = [c.name for c in bench.cameras]
    if rig.calibration:
        from vfmlab.stages.reconstruct import load_calibration_file

        cams = load_calibration_file(Path(rig.calibration))
        by_name = {c.name: c for c in cams}
        if all(n in by_name for n in names):
            return [by_name[n] for n in names], f"calibration {rig.calibration}"
        if len(cams) == len(names):
            return list(cams), f"calibration {rig.calibration}, cameras taken in file order"
        return None, f"the calibration {rig.calibration} has cameras {sorted(by_name)}, the rig {names}"
    scene = getattr(getattr(bench, "sim", None), "scene", None)
    if scene is not None and all(n in scene.camera_names for n in names):
        return [scene.cameras[scene.camera_names.index(n)] for n in names], "the simulated rig's exact cameras"
    return None, "the rig file names no calibration: add [rig] calibration = \"cameras.toml\""


def preflight(bench: Any, rig: Any, console: Any, yes: bool, seconds: float) -> RigCheck | None:
    """``vfmlab run``'s check before anything moves, printed on ``console`` (rich); None when ``seconds`` is 0."""
    if not seconds > 0:
        return None
    from rich.markup import escape as esc

    from vfmlab.stages.errors import StageError

    try:
        calibration = rig_calibration(rig, bench)
    except StageError as exc:
        calibration = (None, f"the rig's calibration cannot be read: {exc}")
    check = check_bench(bench, seconds=seconds, calibration=calibration)
    style = {"OK": "green", "CHECK": "yellow", "FAULT": "bold red"}
    console.print("[bold]Pre-flight check[/]")
    for d in check.devices:
        console.print(f"  [{style[d.verdict]}]{esc(d.line)}[/]")
    console.print(f"  {esc(check.views_line)}")
    if not check.passed:  # the start question follows: the operator decides there (--yes: goes on)
        console.print("[bold yellow]the pre-flight check found faults (above)"
                      + ("; running anyway (--yes)[/]" if yes else ": cancel at the next question to fix them[/]"))
    return check


def keep_check(check: RigCheck, path: Path, console: Any) -> None:
    """Store the pre-flight check (images with detections) in the session, else next to it as PNG files."""
    from rich.markup import escape as esc

    from acquisition.session import SessionError

    try:
        console.print(f"pre-flight check stored as {store_check(check, path)} in {esc(str(path))}")
    except (SessionError, OSError, ValueError) as exc:
        folder = path.with_name(path.stem + "-check")
        log.info("pre-flight check not stored in the session (%s); writing %s", exc, folder)
        try:
            save_check(check, folder)
            console.print(f"pre-flight check images written to {esc(str(folder))}")
        except OSError as err:
            console.print(f"[yellow]the pre-flight check images could not be kept: {esc(str(err))}[/]")
