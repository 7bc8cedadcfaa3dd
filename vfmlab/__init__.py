"""vfmlab: the command line and pipeline layer that wires the stage packages together."""

from __future__ import annotations


def __getattr__(name: str) -> str:
    # ``__version__`` is looked up on first use (PEP 562): importing importlib.metadata costs tens of
    # milliseconds that ``vfmlab --help`` and ``vfmlab info`` need not pay (benchmarks/bench_cli.py).
    if name != "__version__":
        raise AttributeError(f"module 'vfmlab' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("vfmlab")
    except PackageNotFoundError:  # running from a source tree without installation
        value = "0.1.0+source"
    globals()["__version__"] = value
    return value
