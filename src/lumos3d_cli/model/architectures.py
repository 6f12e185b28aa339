"""Model architectures: every size and setting of the network as plain data.

An architecture fully determines the module tree (and so the checkpoint key names and shapes). The
`vggt-1b` architecture has exactly the dimensions of VGGT-1B, so its official checkpoint loads into it;
the smaller architectures keep the same key structure at reduced widths and depths. Checkpoints
store an architecture as JSON through `typed_config` (`to_dict` / `from_dict`), like every config.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from lumos3d_cli.errors import InputError


@dataclass(frozen=True)
class PatchEmbedConfig:
    """How images become patch tokens.

    kind "dinov2": a DINOv2 ViT with `num_register_tokens` registers (cls + registers + learned,
    interpolated position embedding), as in VGGT; kind "conv": a single strided convolution (no
    position embedding: the aggregator's RoPE alone encodes position).
    """

    kind: str = "conv"
    depth: int = 0
    num_heads: int = 0
    mlp_ratio: float = 4.0


APPEARANCES = ("regression", "operator")
MAX_IMAGE_SIZE = 2048  # the network's longer side: VGGT's is 518; beyond this a pass would not fit in memory
_REAL_FIELDS = ("mlp_ratio", "rope_frequency", "layer_scale_init", "voxel_size", "opacity_threshold",
                "gaussian_scale_base", "gaussian_scale_max", "gaussian_scale_min")


@dataclass(frozen=True)
class Architecture:
    """All hyper-parameters of one network size.

    Lengths (`voxel_size`, `gaussian_scale_*`) are relative to the scene scale, the median
    predicted depth (see `model.geometry.scene_scale`), so one setting fits a tabletop and a street.
    """

    name: str
    # input
    image_size: int  # longer image side fed to the network (pixels); also the pos-embed grid
    patch_size: int
    # aggregator (alternating frame / global attention)
    embed_dim: int
    depth: int  # number of frame blocks (= number of global blocks)
    num_heads: int
    mlp_ratio: float
    num_register_tokens: int
    patch_embed: PatchEmbedConfig
    intermediate_layers: tuple[int, int, int, int]  # aggregator layers the DPT heads read
    rope_frequency: float = 100.0
    layer_scale_init: float = 0.01
    # camera head
    camera_trunk_depth: int = 4
    camera_num_heads: int = 16
    camera_iterations: int = 4
    # DPT heads (depth and Gaussian)
    dpt_features: int = 256
    dpt_out_channels: tuple[int, int, int, int] = (256, 512, 1024, 1024)
    depth_head_hidden: int = 32  # channels of the last 3x3 conv of the depth head
    gaussian_head_hidden: int = 128  # channels of the last 3x3 conv of the Gaussian head
    # Gaussians
    sh_degree: int = 4
    voxel_size: float = 0.002
    opacity_threshold: float = 0.001
    gaussian_scale_base: float = 0.001
    gaussian_scale_max: float = 0.3
    gaussian_scale_min: float = 1e-7
    # Appearance: "regression", the Gaussian head regresses every Gaussian's colour (the paper's;
    # VGGT/AnySplat-based checkpoints), or "operator", the illumination head predicts one
    # restoration operator per scene in linear light that colours the Gaussians from the photos'
    # own pixels (model/appearance/; its SH block of the Gaussian head goes unused).
    appearance: str = "regression"
    illumination_hidden: int = 128
    illumination_histogram_bins: int = 16  # 0: the illumination head reads the tokens only
    local_correction_channels: int = 1  # per-view local gain grid channels (1 or 3); 0: none

    def __post_init__(self) -> None:
        sizes = {name: getattr(self, name) for name in ("image_size", "patch_size", "embed_dim", "depth", "num_heads",
                                                         "camera_num_heads", "dpt_features")}
        not_positive = [f"{name} must be positive (got {value!r})" for name, value in sizes.items() if value <= 0]
        if not_positive:  # the divisibility checks below divide by them
            raise ValueError(f"architecture '{self.name}': " + "; ".join(not_positive))
        head_dim = self.embed_dim // self.num_heads
        checks = {
            "embed_dim must be divisible by num_heads": self.embed_dim % self.num_heads == 0,
            "RoPE needs a head dimension divisible by 4": head_dim % 4 == 0,
            "camera head: 2*embed_dim must be divisible by camera_num_heads": (2 * self.embed_dim) % self.camera_num_heads == 0,
            "intermediate_layers must be increasing layer indices below depth": (
                list(self.intermediate_layers) == sorted(set(self.intermediate_layers))
                and 0 <= self.intermediate_layers[0]
                and self.intermediate_layers[-1] < self.depth
            ),
            "image_size must be a multiple of patch_size": self.image_size % self.patch_size == 0,
            "patch_embed.kind must be 'conv' or 'dinov2'": self.patch_embed.kind in ("conv", "dinov2"),
            "dpt_features must be even": self.dpt_features % 2 == 0,
            "sh_degree must be 0..4": 0 <= self.sh_degree <= 4,
            "voxel_size must be positive": self.voxel_size > 0,
            "0 < gaussian_scale_min <= gaussian_scale_max": 0 < self.gaussian_scale_min <= self.gaussian_scale_max,
            "appearance must be 'regression' or 'operator'": self.appearance in APPEARANCES,
            "local_correction_channels must be 0, 1 or 3": self.local_correction_channels in (0, 1, 3),
            "illumination_hidden and illumination_histogram_bins must be positive and non-negative":
                self.illumination_hidden > 0 and self.illumination_histogram_bins >= 0,
            # a checkpoint's header carries these: 0 camera iterations ended in an IndexError, an
            # opacity threshold of 1.5 in a scene of no Gaussians, exit 0
            "camera_iterations must be at least 1": self.camera_iterations >= 1,
            f"image_size must be at most {MAX_IMAGE_SIZE}": self.image_size <= MAX_IMAGE_SIZE,
            "0 <= opacity_threshold < 1": 0 <= self.opacity_threshold < 1,
            "gaussian_scale_base, mlp_ratio and rope_frequency must be positive":
                self.gaussian_scale_base > 0 and self.mlp_ratio > 0 and self.rope_frequency > 0,
            "every number must be finite": all(math.isfinite(getattr(self, name)) for name in _REAL_FIELDS),
        }
        failed = [message for message, ok in checks.items() if not ok]
        if failed:
            raise ValueError(f"architecture '{self.name}': " + "; ".join(failed))

    @property
    def patch_start_index(self) -> int:
        """Tokens before the patches in every frame: 1 camera token + the register tokens."""
        return 1 + self.num_register_tokens

    @property
    def gaussian_channels(self) -> int:
        """Raw Gaussian-head channels: opacity 1, scale 3, quaternion 4, SH 3*(d+1)^2, confidence 1."""
        return 1 + 3 + 4 + 3 * (self.sh_degree + 1) ** 2 + 1


ARCHITECTURES: dict[str, Architecture] = {
    # Small enough to train on two CPU cores: convolutional patch embed, 4+4 narrow blocks.
    "tiny": Architecture(
        name="tiny",
        image_size=224,
        patch_size=14,
        embed_dim=128,
        depth=4,
        num_heads=4,
        mlp_ratio=4.0,
        num_register_tokens=4,
        patch_embed=PatchEmbedConfig(kind="conv"),
        intermediate_layers=(0, 1, 2, 3),
        camera_trunk_depth=2,
        camera_num_heads=4,
        dpt_features=64,
        dpt_out_channels=(32, 64, 128, 128),
        gaussian_head_hidden=32,
        sh_degree=1,
    ),
    # DINOv2 ViT-S/14-reg patch embed, 12+12 blocks at width 384.
    "small": Architecture(
        name="small",
        image_size=518,
        patch_size=14,
        embed_dim=384,
        depth=12,
        num_heads=6,
        mlp_ratio=4.0,
        num_register_tokens=4,
        patch_embed=PatchEmbedConfig(kind="dinov2", depth=12, num_heads=6),
        intermediate_layers=(2, 5, 8, 11),
        camera_num_heads=8,
        dpt_features=128,
        dpt_out_channels=(48, 96, 192, 384),
        gaussian_head_hidden=64,
        sh_degree=2,
    ),
    # DINOv2 ViT-B/14-reg patch embed, 12+12 blocks at width 768.
    "base": Architecture(
        name="base",
        image_size=518,
        patch_size=14,
        embed_dim=768,
        depth=12,
        num_heads=12,
        mlp_ratio=4.0,
        num_register_tokens=4,
        patch_embed=PatchEmbedConfig(kind="dinov2", depth=12, num_heads=12),
        intermediate_layers=(2, 5, 8, 11),
        camera_num_heads=12,
        dpt_features=256,
        dpt_out_channels=(96, 192, 384, 768),
        sh_degree=3,
    ),
    # VGGT-1B exactly (DINOv2 ViT-L/14 with 4 registers, 24+24 blocks at 1024, 16 heads) with
    # AnySplat's Gaussian head (SH degree 4, 84 channels).
    "vggt-1b": Architecture(
        name="vggt-1b",
        image_size=518,
        patch_size=14,
        embed_dim=1024,
        depth=24,
        num_heads=16,
        mlp_ratio=4.0,
        num_register_tokens=4,
        patch_embed=PatchEmbedConfig(kind="dinov2", depth=24, num_heads=16),
        intermediate_layers=(4, 11, 17, 23),
        camera_num_heads=16,
        dpt_features=256,
        dpt_out_channels=(256, 512, 1024, 1024),
        sh_degree=4,
    ),
}
# The tiny network with the appearance operator instead of colour regression (issue 15). Its
# module tree is tiny's plus the illumination head, so a tiny checkpoint initialises it
# (`with_appearance`); the Gaussian head's SH channels go unused.
ARCHITECTURES["tiny-operator"] = dataclasses.replace(ARCHITECTURES["tiny"], name="tiny-operator", appearance="operator")

DEFAULT_ARCHITECTURE = "tiny"


def get_architecture(name: str) -> Architecture:
    """The architecture called `name`; InputError listing the known names otherwise."""
    try:
        return ARCHITECTURES[name]
    except KeyError:
        raise InputError(f"unknown model architecture '{name}'; choose one of: {', '.join(ARCHITECTURES)}") from None
