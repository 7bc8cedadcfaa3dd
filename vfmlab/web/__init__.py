"""The test in a browser: a read-only local page showing a session while ``vfmlab run`` records it.

- :mod:`vfmlab.web.snapshot`: what the page shows, read from the session file (JSON state, camera
  images with the detected markers, the strain map of the last step);
- :mod:`vfmlab.web.server`: the tornado server (127.0.0.1 only, GET only), run in its own process;
- :mod:`vfmlab.web.feed`: the run's side: starts that process and passes it the live results.

See ``docs/guide/live-web.md``. Nothing here is imported by ``vfmlab --help``.
"""

from __future__ import annotations

__all__ = ["WebProcess", "start_web"]


def __getattr__(name: str):
    if name in __all__:
        from vfmlab.web import feed

        return getattr(feed, name)
    raise AttributeError(f"module 'vfmlab.web' has no attribute {name!r}")
