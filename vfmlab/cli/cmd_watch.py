"""``vfmlab watch``: show a session in a browser, while it is being recorded or afterwards."""

from __future__ import annotations

import click

from vfmlab.cli._common import CliError, CliInputError, console

EPILOG = """
\b
Examples:
  vfmlab watch a1.h5                 # then open http://127.0.0.1:8765/
  vfmlab watch a1.h5 --port 9000

The page (read-only, this machine only) shows the protocol's progress, pressure and force against
time, the last image of each camera with its detected markers, the strain map of the last step
and the identified parameters with their 95 % intervals; it refreshes every second. Ctrl-C stops
the server. To watch a test from its start, give 'vfmlab run' the option --web instead.
"""


@click.command(epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="Port on 127.0.0.1 (0: any free port).")
def command(session: str, port: int) -> None:
    """Serve a read-only page showing SESSION (recorded now or complete) on http://127.0.0.1:PORT/."""
    import asyncio
    from pathlib import Path

    from acquisition.session import SessionError, open_session

    if not Path(session).exists():
        raise CliInputError(f"{session}: no such file")
    try:
        with open_session(session):
            pass
    except SessionError as exc:
        raise CliInputError(str(exc)) from None
    from vfmlab.web.priority import idle_priority
    from vfmlab.web.server import serve, warm_up

    warm_up()
    idle_priority()  # a test recorded on this machine keeps the cores (docs/guide/live-web.md)

    def ready(url: str) -> None:
        console.print(f"Watching {session}: open {url} (this machine only; Ctrl-C stops)")

    try:
        asyncio.run(serve(session, port, on_ready=ready))
    except OSError as exc:
        raise CliError(f"--port {port}: cannot listen on 127.0.0.1:{port} ({exc.strerror or exc})") from None
