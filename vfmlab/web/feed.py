"""The run's side of the browser view: start the server process, pass it the live results.

:func:`start_web` starts ``python -m vfmlab.web.server SESSION --feed`` as a separate process
(the server reads the session file by path, so the capture loop never waits on a request) and
returns a :class:`WebProcess`. Its :meth:`WebProcess.observe` is the runner's observer (it only
keeps a reference to the latest state), :meth:`WebProcess.attach` takes the run's
:class:`vfmlab.live_results.LiveResults`; a low-priority daemon thread sends a JSON line to the
server when either changed, at most every ``interval`` s. A server that dies or stops reading
never stops the test: the feed then just stops.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import select
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["WebError", "WebProcess", "live_dict", "start_web", "web_view"]


class WebError(RuntimeError):
    """The server process did not start (port taken, missing library)."""


def _num(x: Any) -> float | None:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def live_dict(state: Any = None, results: Any = None) -> dict[str, Any]:
    """The feed's JSON object from a :class:`acquisition.runner.RunnerState` and a
    :class:`vfmlab.live_results.LiveStatus` (either may be None)."""
    out: dict[str, Any] = {}
    if state is not None:
        out.update(phase=state.phase, step=int(state.step), n_planned=int(state.n_steps),
                   pressure=_num(state.pressure), force=_num(state.force), stable=bool(state.stable),
                   remaining_s=_num(state.remaining_s))
    if results is not None:
        out.update(message=results.message, error=results.error, steps_reconstructed=results.steps_reconstructed,
                   tracked=results.tracked,
                   estimates=[{"model": m, "names": list(e.names), "values": [_num(v) for v in e.values],
                               "stderr": [_num(v) for v in e.stderr], "n_steps": len(e.rows)}
                              for m, e in results.estimates.items()])
        positions = getattr(results, "positions", None)
        if positions is not None and len(positions) >= 2:
            out.update(reference=np.round(positions[0], 9).tolist(), last=np.round(positions[-1], 9).tolist(),
                       last_row=int(getattr(results, "last_row", -1)))
    return out


def _nan_to_none(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, list):
        return [_nan_to_none(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    return obj


class WebProcess:
    """A running server process and the feed thread that passes it the run's live results."""

    def __init__(self, proc: subprocess.Popen, url: str, interval: float = 0.5) -> None:
        self.proc, self.url, self.interval = proc, url, interval
        self._state: Any = None
        self._results: Any = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._feed, name="web-feed", daemon=True)
        self._thread.start()

    # called by the run (never blocks)
    def observe(self, state: Any, bench: Any = None) -> None:
        """The runner's observer: keep the latest state (one assignment in the capture loop)."""
        self._state = state

    def attach(self, results: Any) -> None:
        """The run's LiveResults (``status()`` is thread-safe)."""
        self._results = results

    @staticmethod
    def _clean(live: dict[str, Any]) -> dict[str, Any]:
        """JSON has no NaN: None instead (the page shows "–")."""
        return _nan_to_none(live)

    def _snapshot(self) -> dict[str, Any]:
        results = self._results.status() if self._results is not None else None
        return self._clean(live_dict(self._state, results))

    def _feed(self) -> None:
        # normal priority on purpose: a thread starved by the scheduler while it holds the GIL would stall the
        # capture loop's threads (priority inversion); its work is one small json.dumps per interval
        last = ""
        while not self._stop.wait(self.interval):
            line = json.dumps(self._snapshot(), allow_nan=False)
            if line == last:
                continue
            try:
                self._send(line)
            except (OSError, ValueError):  # the server has gone: the test goes on without it
                log.info("web view: the server process has stopped; the page no longer updates")
                return
            last = line

    @staticmethod
    def _pipe(stream: IO[str] | None) -> IO[str]:
        if stream is None:  # pragma: no cover - start_web always opens both pipes
            raise ValueError("the server process has no pipe")
        return stream

    def _send(self, line: str) -> None:
        stdin = self._pipe(self.proc.stdin)
        stdin.write(line + "\n")
        stdin.flush()

    def close(self, timeout: float = 5.0) -> None:
        """Send the last state, close the feed (the server then stops) and wait for the process."""
        self._stop.set()
        self._thread.join(timeout)
        try:
            self._send(json.dumps(self._snapshot(), allow_nan=False))
            self._pipe(self.proc.stdin).close()
        except (OSError, ValueError):
            pass
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()

    def __enter__(self) -> WebProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_web(session: str | Path, port: int, *, timeout: float = 30.0, interval: float = 0.5) -> WebProcess:
    """Start the server process for ``session`` on 127.0.0.1:``port`` (0: any free port); returns once
    it listens. Raises :class:`WebError` when it does not (port taken, tornado missing)."""
    cmd = [sys.executable, "-m", "vfmlab.web.server", str(Path(session).resolve()), "--port", str(int(port)),
           "--feed"]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, bufsize=1)
    stdout = WebProcess._pipe(proc.stdout)
    ready, _, _ = select.select([stdout], [], [], timeout)
    line = stdout.readline().strip() if ready else ""
    if not line.startswith("http://"):
        proc.kill()
        proc.communicate()
        reason = line.removeprefix("error: ") or f"no answer within {timeout:g} s"
        raise WebError(f"--web: the page's server did not start on port {port}: {reason}")
    return WebProcess(proc, line, interval)




def web_view(session: str | Path, port: int, say: Callable[[str], None] = log.info,
             ) -> contextlib.AbstractContextManager[dict[str, Any]]:
    """``vfmlab run --web``: start the server now (:class:`WebError` if it does not start), report its URL
    with ``say``, and return a context manager giving the keyword arguments of
    :func:`vfmlab.operate.run_session` that feed the page (``observer``, ``on_live_results``);
    leaving it stops the server."""
    web = start_web(session, port)
    say(f"Live view in a browser: {web.url} (this machine only; it stops with the run)")

    @contextlib.contextmanager
    def hooks() -> Iterator[dict[str, Any]]:
        try:
            yield {"observer": web.observe, "on_live_results": web.attach}
        finally:
            web.close()

    return hooks()
