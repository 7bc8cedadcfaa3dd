"""The browser view's HTTP server (tornado): one page, a JSON endpoint and PNG endpoints.

Bound to 127.0.0.1 only; GET only; the session file is the one given at start-up, and no part of
a request ever becomes a file path: the page and its script are read from the package once, the
camera is a number checked against the session's camera list, the step row an integer checked
against the step table. Requests whose ``Host`` is not this machine's loopback name are refused
(a web page elsewhere cannot reach the server through DNS rebinding).

The reads (HDF5, detection, drawing) run in two worker threads (the JSON state; the pictures), so the
event loop keeps answering and the state never waits for a picture,
and the process runs at the lowest ordinary priority (nice 19, :func:`idle_priority`): the capture loop
of ``vfmlab run``, in another process, gets the cores first.

Run as ``python -m vfmlab.web.server SESSION.h5 [--port N] [--feed]`` (what ``vfmlab run --web``
starts): prints the URL on the first line of stdout; with ``--feed`` it reads the run's live
results as JSON lines on stdin (:mod:`vfmlab.web.feed`) and stops at end of input.
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import json
import logging
import sys
import threading
import time
from collections import OrderedDict
from importlib import resources
from pathlib import Path
from typing import Any

import tornado.httpserver
import tornado.netutil
import tornado.web

from vfmlab.web import snapshot
from vfmlab.web.priority import idle_priority

log = logging.getLogger(__name__)

__all__ = ["WebState", "make_app", "serve", "main", "warm_up", "DEFAULT_PORT"]

DEFAULT_PORT = 8765
HOST = "127.0.0.1"
_ASSETS = {"/": ("index.html", "text/html; charset=utf-8"), "/app.js": ("app.js", "text/javascript; charset=utf-8")}
_CSP = "default-src 'self'; img-src 'self' data: blob:; style-src 'self' 'unsafe-inline'; connect-src 'self'"


class WebState:
    """What the handlers share: the session path, the run's live dict, small caches.

    The file is read at most once per ``min_interval`` s whatever the number of pages open (the
    state is cached that long); a picture is drawn once per (camera, step row), and the strain map
    once per new marker positions (a new live step, or a new stored "markers" result). ``live`` is
    replaced whole (never mutated) by the feed thread."""

    def __init__(self, path: str | Path, live: dict[str, Any] | None = None, n_cached: int = 16,
                 min_interval: float = 0.5) -> None:
        self.path = Path(path)
        self.live = live
        self.min_interval = min_interval
        self._state: tuple[float, Any, dict[str, Any]] | None = None  # (monotonic time, live read with, state)
        self._images: OrderedDict[tuple[int, int], bytes] = OrderedDict()
        self._strain: tuple[Any, bytes | None] | None = None
        self._n_cached = n_cached
        self._lock = threading.Lock()

    def state(self) -> dict[str, Any]:
        """The page's state, read from the file at most every ``min_interval`` s (or when the live dict changed)."""
        now, live = time.monotonic(), self.live
        cached = self._state
        if cached is not None and now - cached[0] < self.min_interval and cached[1] is live:
            return cached[2]
        state = snapshot.read_state(self.path, live)
        self._state = (now, live, state)
        return state

    def state_json(self) -> bytes:
        return json.dumps(self.state(), allow_nan=False).encode()

    def camera(self, camera: int, row: int | None) -> bytes:
        """PNG of ``camera`` at ``row`` (default: the last row of the cached state)."""
        if row is None:
            n = int(self.state().get("n_steps", 0))
            row = n - 1 if n > 0 else None
        with self._lock:
            if row is not None and (camera, row) in self._images:
                return self._images[(camera, row)]
        png, row = snapshot.camera_png(self.path, camera, row)
        with self._lock:
            self._images[(camera, row)] = png
            while len(self._images) > self._n_cached:
                self._images.popitem(last=False)
        return png

    def strain(self) -> bytes | None:
        live = self.live
        key = ((live or {}).get("last_row"), tuple(self.state().get("markers_results", ())))
        if self._strain is not None and self._strain[0] == key:
            return self._strain[1]
        png = snapshot.strain_png(self.path, live)
        self._strain = (key, png)
        return png


class _Base(tornado.web.RequestHandler):
    SUPPORTED_METHODS = ("GET",)

    def initialize(self, state: WebState, executor: concurrent.futures.Executor, port: list[int]) -> None:
        self.state, self.executor, self.port = state, executor, port

    def prepare(self) -> None:
        host = self.request.host.lower()
        allowed = {f"{name}:{self.port[0]}" for name in ("127.0.0.1", "localhost")}
        if host not in allowed:
            raise tornado.web.HTTPError(403, "host %s is not this machine's loopback address", host)

    def set_default_headers(self) -> None:
        self.set_header("Cache-Control", "no-store")
        self.set_header("X-Content-Type-Options", "nosniff")
        self.set_header("Content-Security-Policy", _CSP)
        self.set_header("Referrer-Policy", "no-referrer")

    async def blocking(self, fn, *args):
        return await asyncio.get_running_loop().run_in_executor(self.executor, fn, *args)


class AssetHandler(_Base):
    """The page and its script, read from the package once (no request path reaches the disk)."""

    def initialize(self, state: WebState, executor: concurrent.futures.Executor, port: list[int],
                   body: bytes = b"", content_type: str = "") -> None:
        super().initialize(state, executor, port)
        self.body, self.content_type = body, content_type

    def get(self) -> None:
        self.set_header("Content-Type", self.content_type)
        self.write(self.body)


class StateHandler(_Base):
    async def get(self) -> None:
        body = await self.blocking(self.state.state_json)
        self.set_header("Content-Type", "application/json")
        self.write(body)


class CameraHandler(_Base):
    async def get(self, camera: str) -> None:
        row_text = self.get_query_argument("row", "")
        if row_text and not row_text.isdigit():
            raise tornado.web.HTTPError(400, "row must be a step row number")
        row = int(row_text) if row_text and len(row_text) < 9 else None
        try:
            png = await self.blocking(self.state.camera, int(camera), row)
        except LookupError as exc:
            raise tornado.web.HTTPError(404, str(exc)) from None
        self.set_header("Content-Type", "image/png")
        self.write(png)


class StrainHandler(_Base):
    async def get(self) -> None:
        png = await self.blocking(self.state.strain)
        if png is None:
            self.set_status(204)  # no marker positions yet: nothing to draw
            return
        self.set_header("Content-Type", "image/png")
        self.write(png)


def _asset(name: str) -> bytes:
    return resources.files("vfmlab.web").joinpath("static", name).read_bytes()


def make_app(state: WebState, port: list[int]) -> tornado.web.Application:
    """The tornado application; ``port`` is a one-item list holding the bound port (known after binding)."""
    # two readers: the JSON state never queues behind a picture being drawn (detection takes ~0.1 s per image)
    executor = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="web-state")
    pictures = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="web-pictures")
    common: dict[str, Any] = {"state": state, "executor": executor, "port": port}
    drawn = {**common, "executor": pictures}
    routes: list[tuple[str, type[tornado.web.RequestHandler], dict[str, Any]]] = [(route, AssetHandler, {**common, "body": _asset(name), "content_type": kind})
              for route, (name, kind) in _ASSETS.items()]
    routes += [(r"/api/state", StateHandler, common), (r"/api/camera/([0-9]{1,3})\.png", CameraHandler, drawn),
               (r"/api/strain\.png", StrainHandler, drawn)]
    return tornado.web.Application(routes, compress_response=True, serve_traceback=False)


async def serve(path: str | Path, port: int = DEFAULT_PORT, *, on_ready=None, live: WebState | None = None,
                stop: asyncio.Event | None = None) -> None:
    """Serve the view of ``path`` on 127.0.0.1:``port`` (0: any free port) until ``stop`` is set.

    ``on_ready(url)`` is called once the socket is bound; ``live``: a prepared :class:`WebState`."""
    state = live or WebState(path)
    sockets = tornado.netutil.bind_sockets(port, address=HOST)
    bound = [sockets[0].getsockname()[1]]
    server = tornado.httpserver.HTTPServer(make_app(state, bound), xheaders=False)
    server.add_sockets(sockets)
    if on_ready is not None:
        on_ready(f"http://{HOST}:{bound[0]}/")
    try:
        await (stop or asyncio.Event()).wait()
    finally:
        server.stop()


def _read_feed(state: WebState, loop: asyncio.AbstractEventLoop, stop: asyncio.Event) -> None:
    """The run's live results, one JSON object per line on stdin; end of input ends the server."""
    for line in sys.stdin:
        try:
            state.live = json.loads(line)
        except ValueError:
            log.debug("web view: unreadable feed line ignored")
    loop.call_soon_threadsafe(stop.set)


def warm_up() -> None:
    """Import now, at normal priority and before the run starts, what the first requests need (the
    session reader, the marker detector, the plotting): at the lowest priority on a busy machine these
    imports would otherwise delay the page's first picture by many seconds."""
    import matplotlib.figure  # noqa: F401
    import reconstruction  # noqa: F401

    import acquisition.protocol  # noqa: F401
    import acquisition.session  # noqa: F401
    import vfmlab.fields  # noqa: F401


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vfmlab.web.server", description=__doc__.split("\n")[0])
    parser.add_argument("session")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT)
    parser.add_argument("--feed", action="store_true", help="read live results on stdin; stop at its end")
    parser.add_argument("--no-idle", dest="idle", action="store_false",
                        help="keep the normal scheduling priority (default: the lowest, nice 19)")
    args = parser.parse_args(argv)
    warm_up()
    if args.idle:
        idle_priority()

    async def run() -> None:
        stop = asyncio.Event()
        state = WebState(args.session)
        if args.feed:
            threading.Thread(target=_read_feed, args=(state, asyncio.get_running_loop(), stop), daemon=True,
                             name="web-feed").start()

        def ready(url: str) -> None:
            print(url, flush=True)

        await serve(args.session, args.port, on_ready=ready, live=state, stop=stop)

    try:
        asyncio.run(run())
    except OSError as exc:  # the port is taken
        print(f"error: {exc}", flush=True)
        return 1
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
