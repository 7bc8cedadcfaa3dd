"""Reading an OpenPTV working folder (``parameters/ptv.par``, ``cal/*.ori``/``.addpar``, images, ``res/rt_is.*``).

File I/O only; the conversions live in ``reconstruction/calibration_openptv.py``. OpenPTV lengths
are mm and its pixels are offset by +0.5 px from OpenCV's: everything returned here is SI and
OpenCV pixels.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from reconstruction import CalibrationFileError, camera_from_openptv, parse_ptv_par

__all__ = ["is_openptv_folder", "load_cameras", "read_image", "read_rt_is", "read_target_file", "frame_path",
           "physical_media", "describe_media", "calibrate_body_folder", "detect_frame", "observation_depth",
           "body_dots", "self_calibrate_folder", "select_body_folder", "SELFCAL_SETTINGS", "SELFCAL_IMAGES"]


def is_openptv_folder(path: str | Path) -> bool:
    """True for a folder with ``parameters/ptv.par``."""
    return (Path(path) / "parameters" / "ptv.par").is_file()


def _calibration_files(folder: Path, image_name: str) -> tuple[Path, Path | None]:
    ori = folder / (image_name + ".ori")
    add = folder / (image_name + ".addpar")
    if not ori.is_file():
        raise CalibrationFileError(f"{folder}: OpenPTV calibration {ori.name} not found (ptv.par names {image_name})")
    return ori, add if add.is_file() else None


def load_cameras(folder: str | Path, *, media: bool = True) -> list:
    """Cameras (SI, OpenCV pixels) of an OpenPTV folder; ``media=False`` drops the window."""
    folder = Path(folder)
    if not is_openptv_folder(folder):
        raise CalibrationFileError(f"{folder}: not an OpenPTV folder (no parameters/ptv.par)")
    control = parse_ptv_par((folder / "parameters" / "ptv.par").read_text())
    cams = []
    for i, image in enumerate(control["calibration_images"]):
        ori, add = _calibration_files(folder, image)
        cam = camera_from_openptv(f"cam{i + 1}", ori.read_text(), add.read_text() if add else None, control)
        cams.append(cam if media else cam.without_window())
    return cams


def read_image(path: str | Path) -> np.ndarray:
    """A grey image (``uint8``/``uint16``, shape (H, W)); OpenPTV's frames are TIFFs without extension."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def frame_path(folder: str | Path, camera: int, frame: int, *, pattern: str = "img_1/cam{camera}.1000{frame}") -> Path:
    """Path of frame ``frame`` of camera ``camera`` (1-based, as OpenPTV names them)."""
    return Path(folder) / pattern.format(camera=camera, frame=frame)


def read_rt_is(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """OpenPTV 3-D result: points ``(n, 3)`` in m and target indices ``(n, n_cameras)`` (-1 = none)."""
    rows = np.loadtxt(path, skiprows=1, ndmin=2)
    return rows[:, 1:4] * 1e-3, rows[:, 4:].astype(int)


def read_target_file(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Calibration body ``id x y z`` (mm): ids ``(n,)`` and points ``(n, 3)`` in m."""
    rows = np.loadtxt(path, ndmin=2)
    return rows[:, 0].astype(int), rows[:, 1:4] * 1e-3


# ------------------------------------------------------------------------------------- the data set, end to end

#: Particle detection settings of this kind of scene (OpenPTV's targ_rec.par of test_cavity: grey threshold 9,
#: 4..500 px, summed grey >= 150), bright particles on a dark background.
PARTICLE_SETTINGS = {"polarity": "bright", "threshold": 9.0, "pixels_range": (4, 500), "min_sum": 150.0}
#: Calibration-body dots: large bright dots on a dark background.
BODY_DOT_SETTINGS = {"polarity": "bright", "background_px": 41, "threshold": 20.0, "pixels_range": (10, 2000)}
#: Camera model refined on the calibration body (focal length fixed: one view of this body does not fix it; the
#: window's position along its normal fixed: it trades off with the camera's distance, its tilt refined).
BODY_FIT = {"fix_focal": True, "refine_k2": True, "refine_k3": True, "refine_tangential": True, "refine_aspect": True,
            "refine_window_tilt": True}
#: test_cavity's media with ptv.par's two indices swapped back to the physical order (glass 1.46, water 1.33):
#: 0.06-0.14 px lower body RMS in cameras 3 and 4 than as written (OpenPTV's own calibration used them as written).
PHYSICAL_MEDIA = {"indices": (1.46,), "n_bath": 1.33}


def physical_media(window) -> dict | None:
    """The media of ``window`` in physical order, or None when they already are.

    A one-layer window whose glass index is below its bath's (test_cavity's ``ptv.par``: n2 = 1.33, n3 = 1.46,
    i.e. water then glass) has the two swapped back (glass 1.46, water 1.33: :data:`PHYSICAL_MEDIA`): window
    glass (1.46-1.52) is denser than water or saline (1.33-1.34). Returns the keyword arguments for
    ``calibrate_body_folder(..., media=...)`` (``indices``, ``n_bath``)."""
    if window is None or len(window.indices) != 1 or not window.indices[0] < window.n_bath:
        return None
    return {"indices": (float(window.n_bath),), "n_bath": float(window.indices[0])}


def describe_media(window) -> str:
    """``air 1.000 | glass 1.460 (6.0 mm) | water 1.330``: a window's media as people read them."""
    if window is None:
        return "none (straight rays)"
    layers = " | ".join(f"layer {n:.3f} ({t * 1e3:.1f} mm)" for n, t in zip(window.indices, window.thicknesses))
    if len(window.indices) == 1:
        layers = layers.replace("layer", "glass")
    return f"air {window.n_air:.3f} | {layers} | water {window.n_bath:.3f}"


def detect_frame(folder: str | Path, frame: int, n_cameras: int = 4, **settings) -> list[np.ndarray]:
    """Particle centres ``(n_i, 2)`` (OpenCV px) in every camera's image of ``frame``."""
    from reconstruction import detect_particles

    opts = {**PARTICLE_SETTINGS, **settings}
    return [detect_particles(read_image(frame_path(folder, c + 1, frame)), **opts).centres for c in range(n_cameras)]


def calibrate_body_folder(folder: str | Path, seeds: list, *, dot_radius_px: float | None = 6.0,
                          media: dict | None = None, **options) -> list:
    """:func:`~reconstruction.calibration_body.calibrate_from_body` of every camera on ``cal/camN.tif`` and
    ``cal/target_on_a_side.txt``, seeded by ``seeds`` (e.g. the imported calibration). The dots' centres are
    refined on the image (:func:`~reconstruction.calibration_body.refine_dot_centres`, ``dot_radius_px``;
    None keeps the detector's threshold centroids). ``media``: refractive indices for the fine fit instead of the
    seeds' (keys ``indices`` (tuple, one per layer) and/or ``n_bath``): the seeds only give the matching."""
    from reconstruction import calibrate_from_body

    folder = Path(folder)
    _, body = read_target_file(folder / "cal" / "target_on_a_side.txt")
    out = []
    for i, seed in enumerate(seeds):
        px, coarse = _matched_dots(folder, i, seed, body, dot_radius_px)
        out.append(calibrate_from_body(px, body, _with_media(coarse.camera, media), **options))
    return out


def _with_media(camera, media: dict | None):
    """``camera`` with its window's refractive indices replaced by ``media`` (keys ``indices``, ``n_bath``)."""
    if not media or camera.window is None:
        return camera
    return replace(camera, window=replace(camera.window, **media))


def _matched_dots(folder: Path, i: int, seed, body: np.ndarray, dot_radius_px: float | None):
    """Dots of ``cal/cam{i+1}.tif`` matched to the body's points ``(n_body, 2)`` px (refined centres unless
    ``dot_radius_px`` is None) and the coarse fit (fixed focal length, 20 px gate) that matched them."""
    from reconstruction import calibrate_from_body, detect_particles, match_body_points, refine_dot_centres

    image = read_image(folder / "cal" / f"cam{i + 1}.tif")
    dots = detect_particles(image, **BODY_DOT_SETTINGS).centres
    # coarse: a wide gate (dots are ~50 px apart) and a fixed focal length, then the fine match
    coarse = calibrate_from_body(match_body_points(dots, seed, body, gate_px=20.0), body, seed, fix_focal=True)
    px = match_body_points(dots, coarse.camera, body, gate_px=4.0)
    if dot_radius_px is not None:
        px = refine_dot_centres(image, px, radius_px=dot_radius_px)
    return px, coarse


def select_body_folder(folder: str | Path, seeds: list, *, dot_radius_px: float = 6.0, media: dict | None = None,
                       progress=None) -> list:
    """Per camera, :func:`~reconstruction.calibration_body.select_body_model` on the refined dots of
    ``cal/camN.tif``, seeded by ``seeds`` (with ``media`` instead of theirs if given, as
    :func:`calibrate_body_folder`; the seeds' own media match the dots): only the terms the body's dots determine
    over the whole image are refined, the others keep the seed's values (``bench_real_data.py --selfcal-seed
    selected-ptvpar``: the seed the volume self-calibration matches best from). ``progress(done, total, camera
    name)`` after each camera. Returns the ``BodyModelSelection`` per camera."""
    from reconstruction import select_body_model

    folder = Path(folder)
    _, body = read_target_file(folder / "cal" / "target_on_a_side.txt")
    out = []
    for i, seed in enumerate(seeds):
        px, _ = _matched_dots(folder, i, seed, body, dot_radius_px)
        out.append(select_body_model(px, body, _with_media(seed, media)))
        if progress is not None:
            progress(i + 1, len(seeds), seed.name)
    return out


# ------------------------------------------------------------------------------- volume self-calibration of a folder

#: :func:`reconstruction.volume_selfcal.self_calibrate` settings (those of ``benchmarks/bench_real_data.py``):
#: 2 x 2 x 2 sub-volumes; pose, k1, principal point and window tilt refined per camera; soft-L1 scale 1 px; four
#: passes of shrinking (epipolar, radius, keep) tolerances, px; the body as cameras 3-4 see it (from its other side)
#: offset along its normal by a refined distance (``body_sides``; test_cavity: 1.8-2.0 mm, docs/validation/reconstruction.md)
SELFCAL_SETTINGS = {"grid": (2, 2, 2), "free": ("pose", "k1", "principal_point", "window_tilt"), "f_scale_px": 1.0,
                    "schedule": ((4.0, 3.0, 1.5), (3.0, 2.0, 1.0), (2.0, 1.5, 0.7), (1.5, 1.0, 0.5)),
                    "body_sides": True}
#: particle images of a frame in an OpenPTV folder (test_cavity's names: img_1/cam1.10000 ... cam4.10004)
SELFCAL_IMAGES = "img_1/cam{camera}.{frame}"
#: a frame whose image holds fewer particles in a camera is refused (no disparity peak can be formed from it)
MIN_PARTICLES = 50
#: margin added on both sides of criteria.par's depth range: OpenPTV's own points reach 1-6 mm beyond it
DEPTH_MARGIN_M = 5e-3


def observation_depth(folder: str | Path) -> tuple[float, float]:
    """OpenPTV's depth range of the observation volume (``parameters/criteria.par``: Zmin_lay, Zmax_lay), m."""
    path = Path(folder) / "parameters" / "criteria.par"
    try:
        v = [float(x) for x in path.read_text().split()[:6]]
    except (OSError, ValueError) as exc:
        raise CalibrationFileError(f"{path}: cannot read the observation volume ({exc})") from None
    if len(v) < 6:
        raise CalibrationFileError(f"{path}: expected 6 numbers (X_lay, Zmin_lay, Zmax_lay of two layers); got {len(v)}")
    return 1e-3 * min(v[1], v[4]), 1e-3 * max(v[2], v[5])


def body_dots(folder: str | Path, cameras: list) -> tuple[np.ndarray, np.ndarray]:
    """The calibration body's points ``(n_body, 3)`` m and their dots in ``cal/camN.tif`` per camera
    ``(n_cameras, n_body, 2)`` px (threshold centroids matched with ``cameras``, NaN = not found)."""
    from reconstruction import detect_particles, match_body_points

    folder = Path(folder)
    _, pts = read_target_file(folder / "cal" / "target_on_a_side.txt")
    px = [match_body_points(detect_particles(read_image(folder / "cal" / f"cam{i + 1}.tif"), **BODY_DOT_SETTINGS).centres,
                            cam, pts) for i, cam in enumerate(cameras)]
    return pts, np.stack(px)


def self_calibrate_folder(folder: str | Path, cameras: list, frames: list[int], *, images: str = SELFCAL_IMAGES,
                          body_weight=1.0, bounds=None, progress=None, **settings):
    """Volume self-calibration of ``cameras`` on the particles of ``frames`` of an OpenPTV folder.

    Particles detected with :data:`PARTICLE_SETTINGS` in ``folder / images.format(camera=1.., frame=F)``;
    the calibration body's dots (:func:`body_dots`, matched with the folder's own calibration: a seed refined on
    the body matches one more, spurious, dot in test_cavity's camera 2) fix the gauge; ``bounds`` (m) defaults to the region
    seen by >= 3 cameras within ``criteria.par``'s depth range +- :data:`DEPTH_MARGIN_M`
    (:func:`~reconstruction.volume_selfcal.common_view_box`). ``progress(done, total, what)``: detection of
    every image, then each step of the self-calibration. ``settings`` override :data:`SELFCAL_SETTINGS`.

    Returns the :class:`~reconstruction.volume_selfcal.SelfCalibration`, the bounds ``(lo, hi)`` m, the body's
    points ``(n_body, 3)`` m, their dots ``(n_cameras, n_body, 2)`` px and the detections per frame and camera.
    Raises FileNotFoundError naming a missing image and ValueError for a frame with too few particles.
    """
    from reconstruction import common_view_box, detect_particles, self_calibrate

    folder = Path(folder)
    paths = [[folder / images.format(camera=c + 1, frame=f) for c in range(len(cameras))] for f in frames]
    missing = [str(p) for row in paths for p in row if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"{len(missing)} particle image(s) not found, e.g. {missing[0]}")
    if bounds is None:
        z0, z1 = observation_depth(folder)
        bounds = common_view_box(cameras, (z0 - DEPTH_MARGIN_M, z1 + DEPTH_MARGIN_M))
    opts = {**SELFCAL_SETTINGS, **settings}
    total = len(frames) * len(cameras) + len(opts["schedule"]) + 2
    tick = progress if progress is not None else (lambda done, total, what: None)
    detections = []
    for f, row in zip(frames, paths):
        dets = []
        for c, path in enumerate(row):
            dets.append(detect_particles(read_image(path), **PARTICLE_SETTINGS).centres)
            if len(dets[-1]) < MIN_PARTICLES:
                raise ValueError(f"frame {f}, {cameras[c].name}: {len(dets[-1])} particles in {path} "
                                 f"(need >= {MIN_PARTICLES})")
            tick(len(detections) * len(cameras) + c + 1, total, f"particles of frame {f}, {cameras[c].name}")
        detections.append(dets)
    pts, px = body_dots(folder, load_cameras(folder))  # matched as the benchmark does, whatever the seed
    done = len(frames) * len(cameras)
    sc = self_calibrate(detections, cameras, bounds, pts, px, body_weight=body_weight,
                        progress=lambda d, t, what: tick(done + d, total, what), **opts)
    return sc, bounds, pts, px, detections
