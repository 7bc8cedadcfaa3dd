"""vfmlab: the command line and pipeline layer that wires the stage packages together."""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("vfmlab")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.1.0+source"
