"""What the browser view shows, read from the session file: pure readers, no server.

Every function takes the session's path (fixed when the server starts; nothing of a request
names a file) and opens it with :func:`acquisition.session.open_session`, as every other reader
does: a normal open for a finished file, SWMR for one still being written. The run's own live
results (parameters identified while the test runs, the last step's marker positions), when the
server was started by ``vfmlab run --web``, arrive as a plain dict (``live``, see
:mod:`vfmlab.web.feed`) and take precedence over the results stored in the file.

Units: the JSON carries SI values (Pa, N, s, m) plus the display scale of each parameter.
"""

from __future__ import annotations

import io
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["read_state", "camera_png", "strain_png", "MAX_SERIES_POINTS", "IMAGE_WIDTH"]

#: at most this many points of each logged series go to the browser (evenly decimated)
MAX_SERIES_POINTS = 1500
#: camera images are shrunk to at most this width (px) before encoding
IMAGE_WIDTH = 640


def _finite(x: Any) -> float | None:
    """JSON has no NaN: non-finite -> None."""
    x = float(x)
    return x if math.isfinite(x) else None


def _list(a: np.ndarray) -> list:
    return [_finite(v) for v in np.asarray(a, dtype=float).ravel()]


def _decimate(t: np.ndarray, v: np.ndarray, n: int = MAX_SERIES_POINTS) -> tuple[np.ndarray, np.ndarray]:
    if len(t) <= n:
        return t, v
    idx = np.linspace(0, len(t) - 1, n).round().astype(int)
    return t[idx], v[idx]


def _planned_steps(session) -> int | None:
    """Planned steps of the protocol as run (its text and the rig file stored in the session), or None."""
    from acquisition.protocol import ConfigError, parse_protocol, parse_rig

    try:
        rig_text = session.rig_settings.get("config_text", "")
        rig = parse_rig(rig_text, text=rig_text, source="session rig") if rig_text else None
        text = session.protocol_text
        return int(parse_protocol(text, text=text, source="session protocol", rig=rig).n_steps)
    except (ConfigError, ValueError, KeyError, TypeError, AttributeError) as exc:
        log.debug("web view: planned steps unknown: %s", exc)
        return None


def _stored_parameters(session) -> list[dict[str, Any]]:
    """The newest stored identification of each model: values, standard errors, 95 % intervals."""
    out: dict[str, dict[str, Any]] = {}
    for name in session.results("identification"):
        res = session.result(name)
        model = str(res["attrs"].get("model", "?"))
        names = [str(n) for n in res["arrays"].get("parameter_names", [])]
        values = np.asarray(res["arrays"].get("parameters", []), float)
        stderr = np.asarray(res["arrays"].get("stderr", np.full(len(values), np.nan)), float)
        out[model] = _parameter_rows(model, names, values, stderr, source=name,
                                     n_steps=len(res["arrays"].get("ivw", [[]])[0]) if "ivw" in res["arrays"] else None)
    return list(out.values())


def _parameter_rows(model: str, names, values, stderr, source: str, n_steps: int | None) -> dict[str, Any]:
    """One model's parameters for the page: display value, unit and the interval value ± 1.96 stderr."""
    rows = []
    for name, value, se in zip(names, values, stderr):
        try:
            from vfmlab.display import parameter_unit

            scale, unit = parameter_unit(model, name)
        except (KeyError, ValueError, ImportError):
            scale, unit = 1.0, ""
        rows.append({"name": name, "unit": unit, "value": _finite(value / scale), "stderr": _finite(se / scale),
                     "low": _finite((value - 1.96 * se) / scale), "high": _finite((value + 1.96 * se) / scale)})
    return {"model": model, "source": source, "n_steps": n_steps, "parameters": rows}


def live_parameters(live: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The run's live estimates (the feed's dict) as :func:`_parameter_rows` entries."""
    if not live:
        return []
    return [_parameter_rows(e["model"], e["names"], np.asarray(e["values"], float), np.asarray(e["stderr"], float),
                            source="live (run)", n_steps=e.get("n_steps")) for e in live.get("estimates", [])]


def read_state(path: str | Path, live: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything but the pictures, JSON-ready: session status, step table, logged pressure and
    force against time, protocol progress, cameras, latest events and the parameters.

    A missing file is not an error (``vfmlab run --web`` starts the server before the file exists):
    ``{"status": "waiting", ...}``."""
    from acquisition.session import SessionError, open_session

    path = Path(path)
    base: dict[str, Any] = {"file": path.name, "live": _live_summary(live)}
    if not path.exists():
        return {**base, "status": "waiting", "message": "waiting for the session file to be created", "n_steps": 0}
    try:
        with open_session(path) as s:
            return {**base, **_session_state(s), "parameters": live_parameters(live) or _stored_parameters(s)}
    except SessionError as exc:
        return {**base, "status": "unreadable", "message": str(exc), "n_steps": 0}


def _live_summary(live: dict[str, Any] | None) -> dict[str, Any] | None:
    if not live:
        return None
    return {k: live.get(k) for k in ("message", "error", "steps_reconstructed", "tracked", "phase", "pressure",
                                     "force", "step", "n_planned", "remaining_s", "stable")}


def _session_state(s) -> dict[str, Any]:
    steps = s.steps
    t0: float | None = None  # time zero of the curves: the first logged reading (POSIX s)
    series = {}
    for channel in ("pressure", "force"):
        lg = s.log(channel)
        t, v = _decimate(lg["t_wall"], lg["value"])
        if len(lg["t_wall"]):
            t0 = float(lg["t_wall"][0]) if t0 is None else min(t0, float(lg["t_wall"][0]))
        series[channel] = (t, v)
    t0 = t0 if t0 is not None else (float(steps["t_wall"][0]) if len(steps["t_wall"]) else 0.0)
    curves = {channel: {"t": _list(t - t0), "v": _list(v)} for channel, (t, v) in series.items()}
    spec = s.specimen
    return {
        "status": s.status, "message": "", "specimen": spec.specimen_id, "start_time": s.start_time,
        "n_steps": int(s.n_steps), "planned_steps": _planned_steps(s), "cameras": list(s.camera_names),
        "steps": {"block": [int(b) for b in steps["block"]], "stretch": _list(steps["stretch"]),
                  "pressure": _list(steps["pressure"]), "force": _list(steps["force"]),
                  "target_pressure": _list(steps["target_pressure"]), "t": _list(steps["t_wall"] - t0),
                  "active": [bool(a) for a in steps["active"]]},
        "series": curves,
        "markers_results": list(s.results("markers")),
        "events": [{"kind": e["kind"], "message": e["message"]} for e in s.events()[-6:]],
    }


# ---------------------------------------------------------------------------------------- pictures
def _png(image: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def camera_png(path: str | Path, camera: int, row: int | None = None, detect: bool = True) -> tuple[bytes, int]:
    """The frame of camera number ``camera`` (its index in the session's camera list) at step row
    ``row`` (default: the last), shrunk to at most :data:`IMAGE_WIDTH` px wide, with the markers
    that :func:`reconstruction.detect_markers` finds circled in green. Returns ``(png, row)``.

    Raises ``LookupError`` when there is no such camera or row (the server answers 404)."""
    import cv2

    from acquisition.session import open_session

    with open_session(path) as s:
        names = s.camera_names
        n = s.n_steps
        if not 0 <= camera < len(names):
            raise LookupError(f"no camera number {camera}; the session has {len(names)}")
        row = n - 1 if row is None else row
        if not 0 <= row < n:
            raise LookupError(f"no step row {row}; the session has {n}")
        image = np.asarray(s.image(names[camera], row))
    centres = _detections(image) if detect else np.zeros((0, 2))
    grey = image if image.dtype == np.uint8 else _to_uint8(image)
    scale = min(1.0, IMAGE_WIDTH / max(grey.shape[1], 1))
    small = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else grey
    out = cv2.cvtColor(small, cv2.COLOR_GRAY2BGR)
    radius = max(2, int(round(4 * max(scale, 0.5))))
    for x, y in centres * scale:
        cv2.circle(out, (int(round(x)), int(round(y))), radius, (0, 200, 0), 1, lineType=cv2.LINE_AA)
    if out.shape[1] >= 300:  # a caption only where it fits (the page names the camera anyway)
        cv2.putText(out, f"{names[camera]}  row {row}  {len(centres)} markers", (6, 16), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, (0, 220, 255), 1, cv2.LINE_AA)
    return _png(out), row


def _to_uint8(image: np.ndarray) -> np.ndarray:
    """A 16-bit (or float) frame scaled to 0..255 between its minimum and maximum."""
    lo, hi = float(np.min(image)), float(np.max(image))
    return ((image.astype(float) - lo) * (255.0 / max(hi - lo, 1e-12))).astype(np.uint8)


def _detections(image: np.ndarray) -> np.ndarray:
    """Marker centres ``(n, 2)`` px (x, y as OpenCV); none when the detector fails."""
    try:
        from reconstruction import detect_markers

        return np.asarray(detect_markers(image).centres, dtype=float).reshape(-1, 2)
    except Exception as exc:  # noqa: BLE001 - a picture without circles beats an error page
        log.debug("web view: detection failed: %s", exc)
        return np.zeros((0, 2))


def _strain_positions(path: Path, live: dict[str, Any] | None) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(reference (n, 3), last (n, 3), label) marker positions, m: the run's live reconstruction, else
    the newest stored "markers" result; None when neither exists."""
    if live and live.get("reference") is not None and live.get("last") is not None:
        return (np.asarray(live["reference"], float), np.asarray(live["last"], float),
                f"live reconstruction, step row {live.get('last_row', '?')}")
    from acquisition.session import SessionError, open_session

    if not path.exists():
        return None
    try:
        with open_session(path) as s:
            markers = s.latest("markers")
    except SessionError:
        return None
    if markers is None:
        return None
    pos = np.asarray(markers["arrays"]["positions"], float)
    if "visible" in markers["arrays"]:
        pos = np.where(np.asarray(markers["arrays"]["visible"], bool)[..., None], pos, np.nan)
    if pos.ndim != 3 or pos.shape[0] < 2:
        return None
    rows = markers["arrays"].get("step_index", np.arange(len(pos)))
    return pos[0], pos[-1], f"{markers['name']}, step row {int(rows[-1])}"


def strain_png(path: str | Path, live: dict[str, Any] | None = None) -> bytes | None:
    """Circumferential Green-Lagrange strain E11 (%) of the last step relative to the first, per
    triangle on the unrolled reference surface (R theta, z) in mm; None when no marker positions
    exist yet (no reconstruction stored, live results off or not yet past the reference)."""
    found = _strain_positions(Path(path), live)
    if found is None:
        return None
    reference, last, label = found
    from vfmlab.fields import FieldsError, surface_kinematics, surface_mesh

    try:
        mesh = surface_mesh(reference)
        kin, _ = surface_kinematics(mesh, np.stack([reference, last]))
    except (FieldsError, ValueError, np.linalg.LinAlgError) as exc:
        log.debug("web view: no strain map: %s", exc)
        return None
    return _draw_strain(mesh, 100 * kin["E11"][1], label)


def _draw_strain(mesh, e11: np.ndarray, label: str) -> bytes:
    from matplotlib.figure import Figure
    from matplotlib.tri import Triangulation

    s, z = np.nan_to_num(mesh.s) * 1e3, np.nan_to_num(mesh.z) * 1e3
    ok = np.isfinite(e11) & np.all(np.isfinite(mesh.s[mesh.triangles]), axis=1)
    fig = Figure(figsize=(6.4, 3.2), dpi=100, layout="constrained")
    ax = fig.add_subplot()
    if ok.any():
        art = ax.tripcolor(Triangulation(s, z, mesh.triangles[ok]), facecolors=e11[ok], cmap="viridis")
        fig.colorbar(art, ax=ax, label="E11 (%)")
    ax.set(xlabel="R θ (mm)", ylabel="z (mm)", title=f"circumferential strain · {label}")
    ax.set_aspect("equal")
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()
