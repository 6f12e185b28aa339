"""Check that Lumos3D reproduces the reference VGGT implementation on the official checkpoint layout.

Builds the reference network from a local checkout of facebookresearch/vggt (given by path; it
is imported from there, never copied into this repository), gives every parameter random
non-trivial values, saves its state dict exactly as the official `model.pt` is laid out, loads
that file with our `load_model`, runs both networks in float32 on the same random images and
reports the relative errors of the pose encodings (every refinement iteration), depth and depth
confidence.

  python tools/vggt_parity.py /path/to/vggt-checkout --architecture vggt-1b --views 2 --height 350 --width 518
  python tools/vggt_parity.py /path/to/vggt-checkout --architecture small            # reduced, same key layout

Architectures other than vggt-1b are rebuilt from the reference's components (Aggregator with the
matching DINOv2 patch embed, CameraHead, DPTHead) at the architecture's dimensions. The reference
imports `einops` (track head) and `huggingface_hub` (a mix-in base class) at module level;
neither is used on this path, so when missing they are replaced by empty stand-ins.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import types
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch
from torch import nn

from lumos3d_cli.model.architectures import ARCHITECTURES, Architecture
from lumos3d_cli.model.loading import load_model

DINO_NAMES = {384: "dinov2_vits14_reg", 768: "dinov2_vitb14_reg", 1024: "dinov2_vitl14_reg"}


def install_stand_ins() -> None:
    """Empty `einops` and `huggingface_hub.PyTorchModelHubMixin` when they are not installed."""
    try:
        import einops  # noqa: F401
    except ImportError:
        einops = types.ModuleType("einops")
        layers = types.ModuleType("einops.layers")
        layers_torch = types.ModuleType("einops.layers.torch")
        for module in (einops, layers_torch):
            for name in ("rearrange", "repeat", "reduce", "Rearrange", "Reduce"):
                setattr(module, name, None)
        sys.modules.update({"einops": einops, "einops.layers": layers, "einops.layers.torch": layers_torch})
    try:
        from huggingface_hub import PyTorchModelHubMixin  # noqa: F401
    except ImportError:
        hub = types.ModuleType("huggingface_hub")
        hub.PyTorchModelHubMixin = type("PyTorchModelHubMixin", (), {})
        sys.modules["huggingface_hub"] = hub


class ReferenceParts(nn.Module):
    """The reference aggregator, camera head and depth head at an architecture's dimensions."""

    def __init__(self, architecture: Architecture):
        super().__init__()
        from vggt.heads.camera_head import CameraHead
        from vggt.heads.dpt_head import DPTHead
        from vggt.models.aggregator import Aggregator

        self.aggregator = Aggregator(
            img_size=architecture.image_size, patch_size=architecture.patch_size, embed_dim=architecture.embed_dim, depth=architecture.depth,
            num_heads=architecture.num_heads, mlp_ratio=architecture.mlp_ratio, num_register_tokens=architecture.num_register_tokens,
            patch_embed=DINO_NAMES[architecture.embed_dim] if architecture.patch_embed.kind == "dinov2" else "conv",
            rope_freq=architecture.rope_frequency, init_values=architecture.layer_scale_init,
        )
        self.camera_head = CameraHead(
            dim_in=2 * architecture.embed_dim, trunk_depth=architecture.camera_trunk_depth, num_heads=architecture.camera_num_heads,
            mlp_ratio=architecture.mlp_ratio, init_values=architecture.layer_scale_init,
        )
        self.depth_head = DPTHead(
            dim_in=2 * architecture.embed_dim, patch_size=architecture.patch_size, output_dim=2, activation="exp",
            conf_activation="expp1", features=architecture.dpt_features, out_channels=list(architecture.dpt_out_channels),
            intermediate_layer_idx=list(architecture.intermediate_layers),
        )

    def forward(self, images: torch.Tensor) -> dict:
        tokens, patch_start = self.aggregator(images)
        pose_enc_list = self.camera_head(tokens)
        depth, depth_conf = self.depth_head(tokens, images=images, patch_start_idx=patch_start)
        return {"pose_enc": pose_enc_list[-1], "pose_enc_list": pose_enc_list, "depth": depth, "depth_conf": depth_conf}


def build_reference(architecture: Architecture) -> nn.Module:
    if architecture.name == "vggt-1b":
        from vggt.models.vggt import VGGT

        return VGGT()
    return ReferenceParts(architecture)


@torch.no_grad()
def randomize(model: nn.Module, seed: int) -> None:
    """Move every parameter away from its (often trivial) initial value, deterministically:
    LayerScale gains to U(0.05, 0.2), norm gains to 1 + 0.2 N, biases to 0.05 N, learned tokens
    and embeddings to 0.1 N, and weights by noise of their own spread."""
    generator = torch.Generator().manual_seed(seed)
    for name, parameter in model.named_parameters():
        noise = torch.randn(parameter.shape, generator=generator)
        if name.endswith("gamma"):
            parameter.copy_(0.05 + 0.15 * torch.rand(parameter.shape, generator=generator))
        elif parameter.dim() == 1 and "norm" in name and name.endswith("weight"):
            parameter.copy_(1 + 0.2 * noise)
        elif name.endswith("bias"):
            parameter.copy_(0.05 * noise)
        elif name.split(".")[-1] in ("camera_token", "register_token", "cls_token", "pos_embed", "register_tokens", "mask_token", "empty_pose_tokens"):
            parameter.copy_(0.1 * noise)
        else:
            spread = float(parameter.std()) if parameter.numel() > 1 and float(parameter.std()) > 0 else 0.02
            parameter.add_(spread * noise)


def relative_error(ours: torch.Tensor, reference: torch.Tensor) -> dict:
    """max |a - b| / max |b| (scale-relative) and max |a - b| / |b| (element-wise)."""
    difference = (ours.double() - reference.double()).abs()
    return {
        "max_abs": float(difference.max()),
        "relative_to_max": float(difference.max() / reference.double().abs().max()),
        "max_elementwise_relative": float((difference / reference.double().abs().clamp_min(1e-12)).max()),
    }


def run(reference_path: Path, architecture_name: str, views: int, height: int, width: int, seed: int, workdir: Path) -> dict:
    install_stand_ins()
    sys.path.insert(0, str(reference_path))
    architecture = ARCHITECTURES[architecture_name]
    torch.manual_seed(seed)
    reference = build_reference(architecture).eval()
    randomize(reference, seed)
    checkpoint = workdir / "model.pt"
    torch.save(reference.state_dict(), checkpoint)
    ours = load_model(checkpoint, architecture=architecture)
    images = torch.rand(1, views, 3, height, width, generator=torch.Generator().manual_seed(seed + 1))
    with torch.no_grad():
        expected = reference(images)
        actual = ours(images)
    errors = {
        "pose_enc": relative_error(actual.pose_enc, expected["pose_enc"]),
        "depth": relative_error(actual.depth, expected["depth"][..., 0]),
        "depth_conf": relative_error(actual.depth_conf, expected["depth_conf"]),
    }
    for index, (a, b) in enumerate(zip(actual.pose_enc_list, expected["pose_enc_list"], strict=True)):
        errors[f"pose_enc_iteration_{index}"] = relative_error(a, b)
    checked = [errors["pose_enc"]["relative_to_max"], errors["depth"]["max_elementwise_relative"],
               errors["depth_conf"]["relative_to_max"],
               *(errors[name]["relative_to_max"] for name in errors if name.startswith("pose_enc_iteration_"))]
    # NaN anywhere fails (max(1e-6, nan) is 1e-6: a NaN depth passed)
    worst = math.inf if any(not math.isfinite(value) for value in checked) else max(checked)
    return {
        "architecture": architecture_name,
        "input": [1, views, 3, height, width],
        "parameters_compared": sum(t.numel() for k, t in ours.state_dict().items() if not k.startswith("gaussian_head.")),
        "errors": errors,
        "reference_ranges": {
            "pose_enc": [float(expected["pose_enc"].min()), float(expected["pose_enc"].max())],
            "depth": [float(expected["depth"].min()), float(expected["depth"].max())],
            "depth_std": float(expected["depth"].std()),
        },
        "worst_relative_error": worst,
        "passed": worst <= 1e-4,
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "reference_code": sys.modules["vggt.models.aggregator"].__file__,
        "our_class": f"{type(ours).__module__}.{type(ours).__name__}",
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path, help="checkout of facebookresearch/vggt (the folder holding vggt/)")
    parser.add_argument("--architecture", default="vggt-1b", choices=sorted(ARCHITECTURES))
    parser.add_argument("--views", type=int, default=2)
    parser.add_argument("--height", type=int, default=350)
    parser.add_argument("--width", type=int, default=518)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, help="also write the report as JSON here")
    args = parser.parse_args()
    if not (args.reference / "vggt" / "models" / "aggregator.py").is_file():
        parser.error(f"{args.reference} does not hold the vggt package (vggt/models/aggregator.py)")
    with tempfile.TemporaryDirectory(prefix="vggt-parity-") as workdir:
        report = run(args.reference, args.architecture, args.views, args.height, args.width, args.seed, Path(workdir))
    text = json.dumps(report, indent=2)
    print(text)
    if args.output:
        args.output.write_text(text + "\n")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
