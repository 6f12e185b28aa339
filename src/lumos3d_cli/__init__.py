"""lumos3d: single-forward 3D scene restoration from unposed low-light or over-exposed photos."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lumos3d")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
