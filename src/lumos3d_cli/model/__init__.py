"""The Lumos3D network: VGGT-style backbone, camera/depth/Gaussian heads and voxel fusion.

    from lumos3d_cli.model import load_model
    model = load_model("checkpoints/lumos3d.safetensors")  # or VGGT's model.pt, AnySplat's model.safetensors
    prepared = model.prepare(images)                        # [V, 3, H, W] in [0, 1], any size
    output = model(prepared.images[None])                   # Lumos3DOutput
"""

from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import GaussianCounts, Lumos3D, Lumos3DOutput, build_model
from lumos3d_cli.model.preprocess import PreparedImages, prepare_images
from lumos3d_cli.model.presets import DEFAULT_PRESET, PRESETS, ModelPreset, PatchEmbedConfig, get_preset

__all__ = [
    "DEFAULT_PRESET",
    "PRESETS",
    "GaussianCounts",
    "Lumos3D",
    "Lumos3DOutput",
    "ModelPreset",
    "PatchEmbedConfig",
    "PreparedImages",
    "build_model",
    "get_preset",
    "load_model",
    "prepare_images",
]
