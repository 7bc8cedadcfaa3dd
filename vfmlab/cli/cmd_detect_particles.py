"""``vfmlab detect-particles``: small particles (seeding, bright dots) in grey images, with the reject reasons."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from vfmlab.cli._common import console, esc, print_json
from vfmlab.cli._outputs import check_output_path

EPILOG = """
\b
Examples:
  vfmlab detect-particles ../shared/data/openptv-test-cavity/img_1/cam1.10001
  vfmlab detect-particles img_1/cam*.10001 --threshold 6 --min-pixels 3 --max-pixels 500 --min-sum 100 \\
      --split-touching -o particles.csv
"""


@click.command("detect-particles", epilog=EPILOG)
@click.argument("images", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--polarity", type=click.Choice(["bright", "dark"]), default="bright", show_default=True,
              help="Particles brighter than their background (seeding particles, calibration dots) or darker.")
@click.option("--threshold", type=float, default=None,
              help="Grey levels over the local background a pixel needs [default: 4 robust noise sigmas].")
@click.option("--min-pixels", type=int, default=2, show_default=True, help="Smallest accepted particle area, px.")
@click.option("--max-pixels", type=int, default=200, show_default=True, help="Largest accepted particle area, px.")
@click.option("--min-sum", type=float, default=0.0, show_default=True,
              help="Smallest summed grey value over the background (fainter: rejected as low_contrast).")
@click.option("--background-px", type=int, default=9, show_default=True,
              help="Size of the local background estimate, px (larger than a particle).")
@click.option("--split-touching/--no-split-touching", default=False, show_default=True,
              help="Split touching particles at their intensity peaks, as OpenPTV's targ_rec (dense seeding; on "
                   "OpenPTV's test_cavity 78-82 % of its detections get one of ours within 1 px, 57-69 % without). "
                   "Leave off for large dots, whose noisy tops would be split.")
@click.option("--centre", type=click.Choice(["centroid", "gauss3", "gauss3_smoothed", "gauss2d", "hybrid"]),
              default="centroid", show_default=True,
              help="Sub-pixel centre: grey-weighted centroid of the blob, 3-point Gaussian per axis through the "
                   "brightest pixel (of the image or of the image smoothed by a 1 px Gaussian), a 2-D Gaussian "
                   "fit on 5 x 5 px with touching neighbours fitted jointly, or hybrid (the 2-D fit for particles "
                   "split from a blob, the centroid for the others). More precise on synthetic particles; on "
                   "test_cavity's real images the centroid gives the most real matches (docs/validation/reconstruction.md, "
                   "'Particle centres').")
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the particles as CSV: image,u_px,v_px,diameter_px,contrast (OpenCV pixels).")
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@click.option("--json", "as_json", is_flag=True, help="Print the counts per image as JSON.")
def command(images, polarity, threshold, min_pixels, max_pixels, min_sum, background_px, split_touching, centre, out,
            force, as_json):
    """Detect small particles in IMAGES (grey images; OpenPTV's extension-less TIFFs too): threshold over the
    local background, sub-pixel centres (--centre); prints how many were found and rejected, and why."""
    from vfmlab.stages.particles import detect_in_images, particle_settings, write_particles_csv

    settings = particle_settings(polarity, threshold, min_pixels, max_pixels, min_sum, background_px, split_touching,
                                 centre)
    if out is not None:
        check_output_path(out, force=force, inputs=list(images))
    rows = detect_in_images(images, settings)
    if out is not None:
        write_particles_csv(out, rows)
    summary = {"settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.items()},
               "images": [{"image": str(p), "particles": len(d), "rejected": d.reject_counts(),
                           "noise_grey": d.noise} for p, d in rows],
               "out": str(out) if out else None}
    if as_json:
        print_json(summary)
        return
    table = Table(title="Particles")
    for col in ("image", "particles", "rejected (reason: count)", "noise (grey)"):
        table.add_column(col, justify="left" if col.startswith(("image", "rejected")) else "right")
    for p, d in rows:
        why = ", ".join(f"{r}: {n}" for r, n in d.reject_counts().items() if n) or "-"
        table.add_row(esc(p), str(len(d)), esc(why), f"{d.noise:.2f}")
    console.print(table)
    if out is not None:
        console.print(f"wrote {esc(out)}")
