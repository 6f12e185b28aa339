"""The Lumos3D network: VGGT-style backbone, camera/depth/Gaussian heads and voxel fusion.

    from lumos3d_cli.model import load_model
    model = load_model("checkpoints/lumos3d.safetensors")  # or VGGT's model.pt, AnySplat's model.safetensors
    prepared = model.prepare(images)                        # [V, 3, H, W] in [0, 1], any size
    output = model(prepared.images[None])                   # Lumos3DOutput

The names below are imported on first use, so that `lumos3d_cli.model.architectures` (needed by the
checkpoint reader) can be imported without pulling in the whole network.
"""

from importlib import import_module

# public name -> module that defines it
_EXPORTS = {
    "load_model": "lumos3d_cli.model.loading",
    "build_model": "lumos3d_cli.model.lumos3d",
    "GaussianCounts": "lumos3d_cli.model.lumos3d",
    "Lumos3D": "lumos3d_cli.model.lumos3d",
    "Lumos3DOutput": "lumos3d_cli.model.lumos3d",
    "PreparedImages": "lumos3d_cli.model.preprocess",
    "prepare_images": "lumos3d_cli.model.preprocess",
    "DEFAULT_ARCHITECTURE": "lumos3d_cli.model.architectures",
    "ARCHITECTURES": "lumos3d_cli.model.architectures",
    "Architecture": "lumos3d_cli.model.architectures",
    "PatchEmbedConfig": "lumos3d_cli.model.architectures",
    "get_architecture": "lumos3d_cli.model.architectures",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lumos3d_cli.model' has no attribute '{name}'")


def __dir__() -> list[str]:
    return __all__
