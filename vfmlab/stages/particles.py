"""``vfmlab detect-particles``: small particles (seeding, bright dots) in grey images, with the reject reasons
(:func:`reconstruction.particles.detect_particles`), checked settings named after the command's options."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from vfmlab.stages.errors import StageError

__all__ = ["detect_in_images", "particle_settings", "read_grey", "write_particles_csv"]


def read_grey(path: Path) -> np.ndarray:
    """A grey image (OpenPTV's extension-less TIFFs too); StageError naming IMAGES when it cannot be read."""
    from vfmlab import openptv

    try:
        return openptv.read_image(path)
    except FileNotFoundError:
        raise StageError(f"IMAGES: cannot read {path} as a grey image") from None


def particle_settings(polarity, threshold, min_pixels, max_pixels, min_sum, background_px, split_touching,
              centre="centroid") -> dict:
    """Keyword arguments of :func:`reconstruction.particles.detect_particles`; checked here to name the option."""
    if not 1 <= min_pixels <= max_pixels:
        raise StageError(f"--min-pixels/--max-pixels must satisfy 1 <= min <= max; got {min_pixels}, {max_pixels}")
    if threshold is not None and not threshold > 0:
        raise StageError(f"--threshold must be > 0 grey levels; got {threshold}")
    if not background_px >= 3:
        raise StageError(f"--background-px must be >= 3 px (larger than a particle); got {background_px}")
    return {"polarity": polarity, "threshold": threshold, "pixels_range": (min_pixels, max_pixels),
            "min_sum": min_sum, "background_px": background_px, "split_touching": split_touching, "centre": centre}


def write_particles_csv(out: Path, rows: list) -> None:
    """The particles of every image as CSV: image, centre (px), diameter (px), contrast (grey levels)."""
    lines = ["image,u_px,v_px,diameter_px,contrast"]
    for path, det in rows:
        lines += [f"{path},{u:.4f},{v:.4f},{d:.3f},{c:.4f}"
                  for (u, v), d, c in zip(det.centres, det.diameter, det.contrast)]
    out.write_text("\n".join(lines) + "\n")


def detect_in_images(images: Iterable[str | Path], settings: dict) -> list[tuple]:
    """``[(image path, ParticleDetection)]`` for each image, with the keyword arguments of :func:`particle_settings`."""
    from reconstruction.particles import detect_particles

    return [(path, detect_particles(read_grey(path), **settings)) for path in images]
