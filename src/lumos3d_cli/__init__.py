"""lumos3d: single-forward 3D scene restoration from unposed low-light or over-exposed photos.

The public API — the jobs, data in and out, the network — is re-exported here and imported on
first use, so that importing the package (and `lumos3d --help`) stays fast:

    import lumos3d_cli
    scene = lumos3d_cli.restore("dark_photos/")              # the whole job, as `lumos3d restore`
    lumos3d_cli.write_restored_scene(scene, "out/scene.ply")
"""

import os
from importlib import import_module

# OpenMP worker threads (torch's and numba's) spin while they wait by default; where other
# programs share the cores that spinning made refinement steps 2-4x slower on a laptop (and a
# restore 17x slower beside a busy process; no difference on idle cores), so they sleep instead
# unless the user chose otherwise. It takes effect only if set before torch is first imported:
# the command line and `import lumos3d_cli` before torch both do.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# public name -> the module that defines it, and ":name" where it is defined under another name
# (the package's one export table)
_LAZY = {
    # the jobs
    "restore": "lumos3d_cli.pipeline.restore",
    "restore_scene": "lumos3d_cli.pipeline.restore",
    "RestoredScene": "lumos3d_cli.pipeline.restore",
    "write_restored_scene": "lumos3d_cli.pipeline.restore_outputs",
    "evaluate_lom": "lumos3d_cli.pipeline.evaluation",
    "write_eval_report": "lumos3d_cli.pipeline.evaluation",
    # data in and out
    "load_images": "lumos3d_cli.io.images",
    "read_ply": "lumos3d_cli.io.ply",
    "write_ply": "lumos3d_cli.io.ply",
    "read_cameras": "lumos3d_cli.io.camera_files",
    "Cameras": "lumos3d_cli.io.cameras",
    "Gaussians": "lumos3d_cli.io.gaussians",
    # not `render`: that is the subpackage's name, which importing it binds over a function's
    "render_gaussians": "lumos3d_cli.render.render:render",
    # the network
    "build_model": "lumos3d_cli.model.lumos3d",
    "Lumos3D": "lumos3d_cli.model.lumos3d",
    "Lumos3DOutput": "lumos3d_cli.model.lumos3d",
    "GaussianCounts": "lumos3d_cli.model.lumos3d",
    "load_model": "lumos3d_cli.model.loading",
    "prepare_images": "lumos3d_cli.model.preprocess",
    "PreparedImages": "lumos3d_cli.model.preprocess",
    "DEFAULT_ARCHITECTURE": "lumos3d_cli.model.architectures",
    "ARCHITECTURES": "lumos3d_cli.model.architectures",
    "Architecture": "lumos3d_cli.model.architectures",
    "get_architecture": "lumos3d_cli.model.architectures",
    "save_checkpoint": "lumos3d_cli.model.checkpoints",
    "summarize_checkpoint": "lumos3d_cli.model.checkpoints",
}

__all__ = ["__version__", *_LAZY]


def _installed_version() -> str:
    # Importing importlib.metadata takes about 30 ms, an eighth of `lumos3d --help`: only `--version` needs it.
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lumos3d")
    except PackageNotFoundError:  # running from a source tree without installation
        return "0.0.0+unknown"


def __getattr__(name: str):
    if name == "__version__":
        globals()[name] = _installed_version()
        return globals()[name]
    if name in _LAZY:
        module, _, defined_as = _LAZY[name].partition(":")
        value = getattr(import_module(module), defined_as or name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lumos3d_cli' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted(__all__)
