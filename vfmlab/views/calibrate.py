"""What ``vfmlab calibrate`` shows: the board calibration's table and totals, an import's summary, the
self-calibration's figures (rich renderables and lines of text; the command line prints them)."""

from __future__ import annotations

from rich.markup import escape

__all__ = ["board_lines", "import_lines", "selfcal_lines"]


def esc(value) -> str:
    """``value`` as text safe inside rich markup."""
    return escape(str(value))


def _table(result):
    from rich.table import Table

    t = Table(title="Calibration (joint bundle adjustment)")
    for col in ("camera", "views", "RMS (px)", "init RMS (px)", "fx (px)", "fy (px)", "cx (px)", "cy (px)", "k1", "k2"):
        t.add_column(col, justify="right" if col != "camera" else "left")
    for i, (row, cam) in enumerate(zip(result.summary(), result.cameras)):
        t.add_row(esc(row["camera"]), str(row["views"]), f"{row['rms_px']:.3f}", f"{result.initial_rms[i]:.3f}",
                  f"{row['fx']:.1f}±{row['fx_std']:.1f}", f"{row['fy']:.1f}±{row['fy_std']:.1f}",
                  f"{row['cx']:.1f}±{row['cx_std']:.1f}", f"{row['cy']:.1f}±{row['cy_std']:.1f}",
                  f"{cam.dist[0]:+.4f}", f"{cam.dist[1]:+.4f}")
    return t


def board_lines(outcome, session) -> list:
    """The per-camera table, the windows and the totals of a board calibration (rich renderables, in order)."""
    out: list = []
    result, summary = outcome.result, outcome.summary
    out.append(_table(result))
    for w in summary.get("windows", []):
        line = f"window ({esc(', '.join(w['cameras']))}): plane distance {w['plane_distance_mm']:.3f} mm"
        if "plane_distance_std_mm" in w:
            line += (f" ± {w['plane_distance_std_mm']:.3f} mm (moved {w['plane_shift_mm']:+.3f} mm), normal ± "
                     f"{w['normal_std_deg']:.3f} deg (turned {w['normal_change_deg']:.3f} deg), refined")
        else:
            line += ", as the rig file states (not refined)"
        out.append(line)
    out.append(f"total RMS {result.rms_total:.3f} px over {result.n_observations} observations; "
                  f"{result.n_outliers} outliers rejected; converged: {result.converged}")
    if "distortion_choice" in summary:
        out.append(f"distortion: {esc(summary['distortion_choice'])}")
    if summary["out"] is not None:
        out.append(f"wrote {esc(summary['out'])}")
    if outcome.stored:
        out.append(f"stored as {outcome.stored} in {esc(session)}")
    return out


def import_lines(outcome, session) -> list:
    """What an import read, refined, stored and wrote (rich renderables, in order)."""
    out_lines: list = []
    cams, meta, path, out = outcome.cameras, outcome.meta, outcome.summary["imported_from"], outcome.summary["out"]
    out_lines.append(f"imported {len(cams)} cameras from {esc(path)}: {esc(', '.join(c.name for c in cams))}")
    if "body_rms_px" in meta:
        out_lines.append("calibration body RMS: " + ", ".join(f"{esc(n)} {r:.3f} px" for n, r in meta["body_rms_px"].items())
                      + f"; media assumed: {esc(meta['media_assumed'])}")
    if "self_calibration" in meta:
        out_lines += selfcal_lines(meta["self_calibration"])
    if outcome.stored:
        out_lines.append(f"stored as {outcome.stored} in {esc(session)}")
    if out is not None:
        out_lines.append(f"wrote {esc(out)}")
    if not outcome.stored and out is None:
        out_lines.append("nothing stored: give a SESSION (or -o for a calibration without a window) to keep these cameras")
    return out_lines


def selfcal_lines(f: dict) -> list:
    """What the volume self-calibration did (lines of text)."""
    out: list = []
    out.append(f"self-calibration: {esc(f['message'])}; particle RMS after the last pass {f['particle_rms_px'][-1]:.3f} px")
    out.append(f"disparity peaks at the first pass's tolerances: {f['disparity_peak_rms_px_before']:.3f} px RMS "
                  f"(max {f['disparity_peak_max_px_before']:.3f} px) before, {f['disparity_peak_rms_px_after']:.3f} px RMS "
                  f"(max {f['disparity_peak_max_px_after']:.3f} px) after")
    if f["body_far_side_cameras"]:
        out.append(f"body as {esc(', '.join(f['body_far_side_cameras']))} see it (its other side): offset "
                      f"{1e3 * f['body_offset_m']:+.3f} mm along its normal")
    out.append("calibration body RMS before -> after: " + ", ".join(
        f"{esc(n)} {f['body_rms_px_before'][n]:.3f} -> {r:.3f} px" for n, r in f["body_rms_px_after"].items()))
    return out
