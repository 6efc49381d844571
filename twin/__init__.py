"""barrett-twin: a MuJoCo digital twin and hardware bridge of a Barrett BH8 hand squeezing foam."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("barrett-twin")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"
