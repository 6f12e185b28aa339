"""lumos3d: single-forward 3D scene restoration from unposed low-light or over-exposed photos.

The network API is re-exported here and imported on first use, so that importing the package
(and `lumos3d --help`) stays fast:

    import lumos3d_cli
    model = lumos3d_cli.load_model("model.safetensors")
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lumos3d")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

# public name -> module that defines it
_LAZY = {
    "build_model": "lumos3d_cli.model.lumos3d",
    "Lumos3D": "lumos3d_cli.model.lumos3d",
    "Lumos3DOutput": "lumos3d_cli.model.lumos3d",
    "GaussianCounts": "lumos3d_cli.model.lumos3d",
    "load_model": "lumos3d_cli.model.loading",
    "prepare_images": "lumos3d_cli.model.preprocess",
    "PreparedImages": "lumos3d_cli.model.preprocess",
    "ARCHITECTURES": "lumos3d_cli.model.architectures",
    "Architecture": "lumos3d_cli.model.architectures",
    "get_architecture": "lumos3d_cli.model.architectures",
    "save_checkpoint": "lumos3d_cli.io.checkpoints",
    "summarize_checkpoint": "lumos3d_cli.io.checkpoints",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lumos3d_cli' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted(__all__)
