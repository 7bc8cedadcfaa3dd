"""The test in a browser (vfmlab.web): JSON and PNG endpoints on a session, updates while a writer
appends steps (SWMR, as the runner writes), the page in headless Chromium, paths that cannot escape."""

from __future__ import annotations

import http.client
import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, StepRecord
from rig_sim.synthetic_session import make_session
from tests.test_e2e_report import _chromium
from vfmlab.cli import main
from vfmlab.web.feed import start_web

PNG = b"\x89PNG\r\n\x1a\n"
POLL_PERIOD = 1.0  # s, the page's (vfmlab/web/static/app.js)
CAMS = [CameraSpec(f"cam{i}", "simulated", 80, 60) for i in range(2)]


def _get(url: str, path: str, method: str = "GET", host: str | None = None) -> tuple[int, str, bytes]:
    """(status, content type, body) of a raw request: the path is sent exactly as given."""
    hostport = url.removeprefix("http://").rstrip("/")
    conn = http.client.HTTPConnection(hostport, timeout=30)
    try:
        conn.putrequest(method, path, skip_host=host is not None, skip_accept_encoding=True)
        if host is not None:
            conn.putheader("Host", host)
        conn.endheaders()
        r = conn.getresponse()
        return r.status, r.getheader("Content-Type", ""), r.read()
    finally:
        conn.close()


def _state(url: str) -> dict:
    status, kind, body = _get(url, "/api/state")
    assert status == 200 and kind.startswith("application/json"), (status, body[:300])
    return json.loads(body)


@pytest.fixture
def complete(tmp_path):
    path = make_session(tmp_path / "done.h5")
    with start_web(path, 0) as web:
        yield web.url


def _step(k: int) -> StepRecord:
    return StepRecord(block=0, stretch=1.1, target_pressure=1000.0 * k, pressure=1000.0 * k + 1, force=0.1 * k,
                      t_monotonic=float(k), t_wall=1.7e9 + k)


def _frame(k: int) -> np.ndarray:
    img = np.full((60, 80), 200, np.uint8)
    img[20:26, 10 + 5 * k:16 + 5 * k] = 20  # a dark marker that moves with the step
    return img


@pytest.fixture
def recording(tmp_path):
    """A session being written (SWMR writer in this process, as the runner's) with one step, and its server."""
    path = tmp_path / "live.h5"
    spec = SpecimenInfo("live-01", 1e-2, 3e-2, 1e-3, "")
    with SessionWriter.create(path, spec, cameras=CAMS, protocol_text="[test]\n", rig={},
                              instruments={}) as writer:
        writer.append_log("pressure", np.arange(3.0), 1.7e9 + np.arange(3.0), np.array([0.0, 500.0, 1000.0]))
        writer.add_step(_step(0), images={c.name: _frame(0) for c in CAMS})
        with start_web(path, 0, interval=0.1) as web:
            yield writer, web


def test_json_and_png_of_a_complete_session(complete):
    state = _state(complete)
    assert state["status"] == "complete" and state["n_steps"] == 7 and state["cameras"] == [f"cam{i}" for i in range(4)]
    assert len(state["series"]["pressure"]["t"]) == 50 and len(state["steps"]["pressure"]) == 7
    fung = {m["model"]: m for m in state["parameters"]}["fung"]
    beta = fung["parameters"][0]
    assert beta["name"] == "beta" and beta["low"] < beta["value"] < beta["high"]
    for path in ("/api/camera/0.png", "/api/camera/3.png?row=2", "/api/strain.png"):
        status, kind, body = _get(complete, path)
        assert status == 200 and kind == "image/png" and body.startswith(PNG), path
    for path, kind in (("/", "text/html"), ("/app.js", "text/javascript")):
        status, got, body = _get(complete, path)
        assert status == 200 and got.startswith(kind) and body


@pytest.mark.parametrize("path, expected", [
    ("/../../../../etc/passwd", 404), ("/%2e%2e/%2e%2e/etc/passwd", 404), ("/static/index.html", 404),
    ("/api/camera/..%2f..%2fetc%2fpasswd.png", 404), ("/api/camera/0.png/../../../etc/passwd", 404),
    ("/api/camera/0.png?row=../../x", 400), ("/api/camera/0.png?row=99", 404), ("/api/camera/4.png", 404),
    ("/api/camera/-1.png", 404), ("/done.h5", 404), ("//etc/passwd", 404), ("/app.js?x=/etc/passwd", 200),
])
def test_request_paths_cannot_escape(complete, path, expected):
    status, _, body = _get(complete, path)
    assert status == expected, (path, status)
    assert b"root:" not in body


def test_get_only_and_this_machine_only(complete):
    for method in ("POST", "PUT", "DELETE"):
        assert _get(complete, "/api/state", method=method)[0] == 405
    assert _get(complete, "/api/state", host="attacker.example:80")[0] == 403  # DNS rebinding
    assert complete.startswith("http://127.0.0.1:")


def test_a_captured_step_shows_in_the_next_poll(recording):
    writer, web = recording
    first = _state(web.url)
    assert first["status"] == "running" and first["n_steps"] == 1
    writer.add_step(_step(1), images={c.name: _frame(1) for c in CAMS})
    time.sleep(POLL_PERIOD)  # the page's next poll (the server reads the file at most every 0.5 s)
    assert _state(web.url)["n_steps"] == 2
    status, _, png = _get(web.url, "/api/camera/1.png?row=1")
    assert status == 200 and png.startswith(PNG)
    assert _get(web.url, "/api/strain.png")[0] == 204  # no marker positions yet


def test_live_results_of_the_run_reach_the_page(recording):
    from acquisition.runner import RunnerState

    _, web = recording
    web.observe(RunnerState(phase="stabilising", step=1, n_steps=4, pressure=2000.0, force=0.3))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not (_state(web.url)["live"] or {}).get("phase"):
        time.sleep(0.1)
    live = _state(web.url)["live"]
    assert live["phase"] == "stabilising" and live["pressure"] == 2000.0 and live["n_planned"] == 4


def _dump_dom(chromium: str, url: str, tmp_path: Path) -> subprocess.CompletedProcess:
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0",
           "--virtual-time-budget=4000", "--dump-dom", url]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=90, env=dict(os.environ, HOME=str(tmp_path)))
    assert proc.returncode == 0, proc.stderr[-2000:]
    console = [line for line in proc.stderr.splitlines() if "CONSOLE" in line or "Uncaught" in line]
    assert not console, console
    return proc


@pytest.mark.timeout(240)
def test_page_in_headless_chromium_updates_without_console_errors(recording, tmp_path):
    chromium = _chromium()
    writer, web = recording
    dom = _dump_dom(chromium, web.url, tmp_path).stdout
    assert 'data-steps="1"' in dom and "live.h5" in dom and 'src="/api/camera/1.png?row=0"' in dom
    writer.add_step(_step(1), images={c.name: _frame(1) for c in CAMS})
    dom = _dump_dom(chromium, web.url, tmp_path).stdout
    assert 'data-steps="2"' in dom and 'src="/api/camera/1.png?row=1"' in dom and "2 / " in dom


@pytest.mark.timeout(240)
def test_page_of_a_complete_session_in_headless_chromium(complete, tmp_path):
    dom = _dump_dom(_chromium(), complete, tmp_path).stdout
    assert 'data-steps="7"' in dom and "95 % interval" in dom and "delfino" in dom
    assert 'id="strain" alt="strain map" src="blob:' in dom


def test_watch_refuses_what_is_not_a_session(tmp_path, capsys):
    assert main(["watch", str(tmp_path / "missing.h5")]) == 2
    (tmp_path / "x.h5").write_text("not hdf5")
    assert main(["watch", str(tmp_path / "x.h5")]) == 2
    assert "not a session file" in capsys.readouterr().err


ROOT = Path(__file__).resolve().parents[1]
SHORT = """
[preconditioning]
pressure_cycles = 0
stretch_cycles = 0
[stability]
band_mmHg = 1.0
dwell_s = 0.1
timeout_s = 20
[test]
stretches = [1.1]
pressures_mmHg = [0, 50, 100]
[calibration]
views = 0
"""


@pytest.mark.timeout(180)
def test_run_web_prints_the_address_and_the_server_ends_with_the_run(tmp_path, capsys):
    (tmp_path / "p.toml").write_text(SHORT)
    rig = (ROOT / "examples" / "sim-rig.toml").read_text().replace("width = 640, height = 480",
                                                                   "width = 320, height = 240")
    (tmp_path / "rig.toml").write_text(rig)
    out = tmp_path / "w.h5"
    rc = main(["run", str(tmp_path / "p.toml"), "--specimen", str(ROOT / "examples" / "specimen.toml"), "-o",
               str(out), "--rig", str(tmp_path / "rig.toml"), "--sim", "--sim-speed", "5", "--yes", "--web", "0"])
    text = capsys.readouterr().out
    assert rc == 0 and "Live view in a browser: http://127.0.0.1:" in text and "Session complete" in text
    servers = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    assert f"vfmlab.web.server {out}" not in servers  # the page's process ended with the run


def test_run_web_on_a_taken_port_stops_before_anything_moves(tmp_path, capsys):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rc = main(["run", str(ROOT / "examples" / "paper-protocol.toml"), "--specimen",
                   str(ROOT / "examples" / "specimen.toml"), "-o", str(tmp_path / "x.h5"), "--sim", "--yes",
                   "--web", str(port)])
    assert rc == 1 and f"the page's server did not start on port {port}" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()


def test_live_results_give_the_parameters_and_the_strain_map(tmp_path):
    """The run's LiveStatus -> the feed's JSON line -> the page's parameters and strain map."""
    from rig_sim.synthetic_session import synthetic_tube
    from vfmlab.live_results import LiveEstimate, LiveStatus
    from vfmlab.web import snapshot
    from vfmlab.web.feed import WebProcess, live_dict

    pos = synthetic_tube(120)[0]
    est = LiveEstimate("fung", ("beta", "alpha11", "alpha22", "alpha12"), np.array([5e3, 14.0, 7.0, 0.1]),
                       np.array([200.0, 0.5, 0.3, np.nan]), np.arange(4), 1e-3, ())
    status = LiveStatus(steps_reconstructed=4, estimates={"fung": est}, positions=pos[:4], last_row=3)
    live = json.loads(json.dumps(WebProcess._clean(live_dict(None, status)), allow_nan=False))
    session = make_session(tmp_path / "s.h5", with_results=False)
    state = snapshot.read_state(session, live)
    beta, _, _, alpha12 = state["parameters"][0]["parameters"]
    assert state["parameters"][0]["source"] == "live (run)" and beta["unit"] == "kPa"
    assert beta["value"] == pytest.approx(5.0) and beta["high"] == pytest.approx(5.0 + 1.96 * 0.2)
    assert alpha12["stderr"] is None and alpha12["low"] is None  # no interval rather than NaN
    assert snapshot.strain_png(session, live).startswith(PNG)
    assert snapshot.strain_png(session, None) is None  # no stored reconstruction
