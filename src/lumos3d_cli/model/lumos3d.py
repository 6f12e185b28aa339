"""The assembled network: images -> cameras, depth, per-pixel Gaussians -> fused scene Gaussians."""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass, field

import torch
from torch import nn

from lumos3d_cli.checks import require_finite, require_unit_range
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.model.architectures import DEFAULT_ARCHITECTURE, Architecture, get_architecture
from lumos3d_cli.model.appearance.gaussian_colours import with_operator_colours
from lumos3d_cli.model.appearance.illumination_head import IlluminationHead
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.backbone import Aggregator
from lumos3d_cli.model.gaussian_adapter import activate_gaussians, split_confidence
from lumos3d_cli.model.geometry import scene_scale, unproject_depth
from lumos3d_cli.model.heads.camera import CameraHead
from lumos3d_cli.model.heads.dpt import DepthHead
from lumos3d_cli.model.heads.gaussian import GaussianHead
from lumos3d_cli.model.pixel_footprint import footprint_voxel_sizes, pixel_footprint
from lumos3d_cli.model.pose_encoding import decode_pose
from lumos3d_cli.model.preprocess import PreparedImages, prepare_images
from lumos3d_cli.model.voxelize import covering_shapes, voxelize

logger = logging.getLogger(__name__)


@dataclass
class GaussianCounts:
    """pixels: per-pixel Gaussians (V*H*W); voxels: after fusion; pruned: voxels dropped for
    opacity below the threshold; kept = voxels - pruned."""

    pixels: int
    voxels: int
    pruned: int

    @property
    def kept(self) -> int:
        return self.voxels - self.pruned


@dataclass
class Lumos3DOutput:
    """Everything one forward pass predicts for B scenes of V views of H x W pixels.

    pose_enc [B, V, 9] (last refinement) and pose_enc_list (every refinement);
    extrinsics [B, V, 3, 4] world->camera (the first view is approximately the world frame);
    intrinsics [B, V, 3, 3] in pixels of the H x W network image; depth, depth_conf [B, V, H, W];
    world_points [B, V, H, W, 3] (depth unprojected at pixel centres); pixel_confidence
    [B, V, H, W] fusion logits; pixel_gaussians and gaussians (fused, pruned): one Gaussians per
    scene, pixel rows in (view, row, column) order; scene_scale [B] median depth, the unit of
    voxel and Gaussian sizes; counts per scene; appearance: the scenes' restoration operators
    (architectures with appearance "operator"; None for colour regression), which coloured the
    Gaussians here and colour the full-resolution photos through `restore_photos`.
    """

    pose_enc: torch.Tensor
    pose_enc_list: list[torch.Tensor]
    extrinsics: torch.Tensor
    intrinsics: torch.Tensor
    depth: torch.Tensor
    depth_conf: torch.Tensor
    world_points: torch.Tensor
    pixel_confidence: torch.Tensor
    pixel_gaussians: list[Gaussians]
    gaussians: list[Gaussians]
    scene_scale: torch.Tensor
    counts: list[GaussianCounts] = field(default_factory=list)
    appearance: AppearanceOperator | None = None

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the network images."""
        return int(self.depth.shape[-1]), int(self.depth.shape[-2])

    def cameras(self, scene: int = 0) -> Cameras:
        """The predicted cameras of one scene as the project's camera type (network pixels)."""
        views = self.extrinsics.shape[1]
        return Cameras(self.extrinsics[scene].detach(), self.intrinsics[scene].detach(), [self.image_size] * views)


@dataclass
class Lumos3DPrediction:
    """What the heads predict for B scenes of V views of H x W pixels, before Gaussians are placed:
    pose_enc_list (every camera refinement, [B, V, 9] each); extrinsics [B, V, 3, 4] world->camera
    and intrinsics [B, V, 3, 3] (network pixels) decoded from the last; depth, depth_conf
    [B, V, H, W]; params [B, V, H, W, K-1] raw Gaussian parameters (gaussian_adapter layout);
    confidence [B, V, H, W] fusion logits; appearance: the scenes' restoration operators (None for
    colour regression; with it, params carry the restored colours)."""

    pose_enc_list: list[torch.Tensor]
    extrinsics: torch.Tensor
    intrinsics: torch.Tensor
    depth: torch.Tensor
    depth_conf: torch.Tensor
    params: torch.Tensor
    confidence: torch.Tensor
    appearance: AppearanceOperator | None = None

    def require_finite(self, hint: str) -> None:
        """NonFiniteError naming the first prediction that holds NaN or Inf, followed by `hint`."""
        for name in ("extrinsics", "intrinsics", "depth", "depth_conf", "params", "confidence"):
            require_finite(f"the network's {name}", getattr(self, name), hint)
        if self.appearance is not None:
            for name, values in (("curve", self.appearance.curve_slopes), ("colour matrix", self.appearance.matrix),
                                 ("local correction", self.appearance.local_log2_gain)):
                if values is not None:
                    require_finite(f"the network's restoration {name}", values, hint)


class Lumos3D(nn.Module):
    """The network of the paper. Submodule names equal VGGT's (`aggregator`, `camera_head`,
    `depth_head`) plus `gaussian_head` (AnySplat's `gaussian_param_head`)."""

    def __init__(self, architecture: Architecture):
        super().__init__()
        self.architecture = architecture
        self.aggregator = Aggregator(architecture)
        self.camera_head = CameraHead(architecture)
        self.depth_head = DepthHead(architecture)
        self.gaussian_head = GaussianHead(architecture)
        self.illumination_head = (
            IlluminationHead(
                2 * architecture.embed_dim, architecture.patch_start_index, architecture.patch_size,
                architecture.illumination_hidden, histogram_bins=architecture.illumination_histogram_bins,
                local_channels=architecture.local_correction_channels,
            )
            if architecture.appearance == "operator" else None
        )
        # Where the weights came from (set by `load_model`; `build_model` marks them random).
        self.provenance: dict = {}

    @property
    def token_layers(self) -> list[int]:
        """Aggregator layers the heads read: the DPT layers and the last (camera head)."""
        return sorted(set(self.architecture.intermediate_layers) | {self.architecture.depth - 1})

    def set_gradient_checkpointing(self, enabled: bool) -> None:
        """Recompute aggregator blocks in the backward pass instead of storing activations."""
        self.aggregator.set_gradient_checkpointing(enabled)

    def prepare(self, images: torch.Tensor, mode: str = "resize") -> PreparedImages:
        """Any-size images [..., 3, H, W] in [0, 1] -> this architecture's network size (`prepare_images`)."""
        return prepare_images(images, self.architecture.image_size, self.architecture.patch_size, mode)

    def _checked_images(self, images: torch.Tensor) -> torch.Tensor:
        """The images, checked, in the weights' floating-point type (a float64 or bf16 batch
        would otherwise meet float32 weights in the first convolution; autocast still applies)."""
        patch = self.architecture.patch_size
        if images.dim() != 5 or images.shape[2] != 3 or images.shape[0] == 0 or images.shape[1] == 0:
            raise InputError(f"model input must be [B, V, 3, H, W] images with B and V at least 1, got shape "
                             f"{tuple(images.shape)}")
        if not images.is_floating_point():
            raise InputError(f"model input images are {images.dtype}; give floating-point images in [0, 1]")
        height, width = images.shape[-2:]
        if height < patch or width < patch or height % patch or width % patch:
            raise InputError(
                f"image size {width}x{height} is not a positive multiple of the patch size {patch}; "
                "pass the images through Lumos3D.prepare / prepare_images first"
            )
        require_finite("model input images", images)
        require_unit_range("model input images", images)
        return images.to(next(self.parameters()).dtype)

    def fuse_scene(
        self, points: torch.Tensor, params: torch.Tensor, confidence: torch.Tensor, scale: torch.Tensor,
        voxel_size: float | torch.Tensor | None = None, fuse_views: torch.Tensor | None = None,
        fuse_pixels: torch.Tensor | None = None, covering: bool = False,
    ) -> tuple[Gaussians, Gaussians, GaussianCounts]:
        """One scene: points [V, H, W, 3], raw parameters [V, H, W, K-1], confidence [V, H, W],
        scene scale -> (pixel Gaussians, fused and pruned Gaussians, counts).

        voxel_size overrides the architecture's (relative to the scene scale): one number, or
        [V, H, W] one per pixel (`model.pixel_footprint`); fuse_views [V] bool keeps
        only those views' pixel Gaussians in the fused scene (the others still shaped the cameras
        and depth; evaluation's holdout protocol uses this); fuse_pixels [V, H, W] bool keeps only
        those pixels (e.g. the ones whose depth other views confirm); covering: voxels of several
        members take the shape that spans them (`voxelize.covering_shapes`, not differentiated)
        instead of the mean shape."""
        mask = None if fuse_views is None else fuse_views[:, None, None].expand(points.shape[:3])
        if fuse_pixels is not None:
            mask = fuse_pixels if mask is None else mask & fuse_pixels
        if mask is not None:
            if not bool(mask.any()):
                raise ValueError("fuse_views / fuse_pixels selects no view or pixel")
            points, params, confidence = points[mask], params[mask], confidence[mask]
            if isinstance(voxel_size, torch.Tensor):
                voxel_size = voxel_size[mask]
        points = points.reshape(-1, 3)
        params = params.reshape(points.shape[0], -1)
        relative = self.architecture.voxel_size if voxel_size is None else voxel_size
        if isinstance(relative, torch.Tensor):
            relative = relative.reshape(-1)
        pixels = activate_gaussians(points, params, scale, self.architecture)
        fused = voxelize(points, params, confidence.reshape(-1), relative * scale)
        voxels = activate_gaussians(fused.points, fused.features, scale, self.architecture)
        if covering:
            voxels = covering_shapes(voxels, pixels, fused, self.architecture.gaussian_scale_min * scale)
        keep = voxels.opacities >= self.architecture.opacity_threshold
        return pixels, voxels.select(keep), GaussianCounts(points.shape[0], len(fused), int((~keep).sum()))

    def predict(self, images: torch.Tensor) -> Lumos3DPrediction:
        """The heads' predictions for images [B, V, 3, H, W] in [0, 1] (H and W multiples of the
        patch size), before any Gaussian is placed: cameras, depth, raw Gaussian parameters.

        The aggregator follows any enclosing autocast (e.g. bf16); the heads run in float32, as
        in VGGT.
        """
        images = self._checked_images(images)
        height, width = images.shape[-2:]
        tokens = self.aggregator(images, self.token_layers)
        with torch.autocast(images.device.type, enabled=False):
            tokens = {layer: t.float() for layer, t in tokens.items()}
            images = images.float()
            pose_enc_list = self.camera_head(tokens[self.architecture.depth - 1])
            depth, depth_conf = self.depth_head(tokens, images)
            raw = self.gaussian_head(tokens, images)  # [B, V, K, H, W]
            appearance = None
            if self.illumination_head is not None:
                appearance = self.illumination_head(tokens[self.architecture.depth - 1], images)
            del tokens  # the layer tokens are the largest tensors; free them before fusion
            extrinsics, intrinsics = decode_pose(pose_enc_list[-1], (height, width))
            params, confidence = split_confidence(raw.permute(0, 1, 3, 4, 2))  # [B, V, H, W, K-1], [B, V, H, W]
            if appearance is not None:
                # Each pixel Gaussian takes its restored pixel's colour at the network size; the
                # pipeline recolours from the full-resolution photos (`restore_photos`).
                params = with_operator_colours(params, appearance.apply(images), self.architecture.sh_degree)
        return Lumos3DPrediction(pose_enc_list, extrinsics, intrinsics, depth, depth_conf, params, confidence, appearance)

    def predict_appearance(self, images: torch.Tensor) -> AppearanceOperator:
        """images [B, V, 3, H, W] in [0, 1] (network size) -> the scenes' restoration operators,
        running only the aggregator's last layer and the illumination head (no geometry): for
        one-view samples such as exposure brackets, and 2D restoration."""
        if self.illumination_head is None:
            raise InputError(f"architecture '{self.architecture.name}' regresses colours (appearance 'regression'); "
                             "it predicts no restoration operator")
        images = self._checked_images(images)
        last = self.architecture.depth - 1
        tokens = self.aggregator(images, [last])[last]
        return self.illumination_head(tokens, images)

    def assemble(
        self, prediction: Lumos3DPrediction, extrinsics: torch.Tensor | None = None,
        intrinsics: torch.Tensor | None = None, depth: torch.Tensor | None = None,
        voxel_size: float | None = None, fuse_views: torch.Tensor | None = None, fuse_pixels: torch.Tensor | None = None,
        footprint_scale: float | None = None,
    ) -> Lumos3DOutput:
        """Place and fuse the Gaussians of `prediction`. By default they sit on the predicted depth
        seen from the predicted cameras; a caller with better geometry (registered cameras
        extrinsics [B, V, 3, 4] and intrinsics [B, V, 3, 3] in network pixels, depth [B, V, H, W]
        aligned to them) passes it instead. `voxel_size`, `fuse_views` [V] and `fuse_pixels`
        [B, V, H, W] (bool) are passed to `fuse_scene`. Runs in float32.

        The voxels are one size, `voxel_size` (default: the architecture's; training relies on
        it), unless `footprint_scale` is given: then each pixel Gaussian's voxel is that multiple
        of its pixel footprint, the world size of one network pixel in the finest fused view that
        holds it, rounded to a power of two of the scene scale (`model.pixel_footprint`), and a
        voxel that merges several pixels takes the shape that spans them (`fuse_scene` covering;
        not differentiated, for inference)."""
        if footprint_scale is not None and voxel_size is not None:
            raise ValueError("give voxel_size or footprint_scale, not both")
        for name, value in (("voxel_size", voxel_size), ("footprint_scale", footprint_scale)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)
                                      or not (math.isfinite(value) and value > 0)):
                raise InputError(f"{value!r}: give a positive number (relative to the scene's scale)", parameter=name)
        placed_depth = prediction.depth if depth is None else depth
        for name, mask, shape in (("fuse_views", fuse_views, tuple(placed_depth.shape[1:2])),
                                  ("fuse_pixels", fuse_pixels, tuple(placed_depth.shape))):
            if mask is not None and (not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool or mask.shape != shape):
                got = f"{mask.dtype} of shape {tuple(mask.shape)}" if isinstance(mask, torch.Tensor) else type(mask).__name__
                raise InputError(f"must be a bool tensor of shape {list(shape)}, got {got}", parameter=name)
        with torch.autocast(prediction.depth.device.type, enabled=False):
            extrinsics = prediction.extrinsics if extrinsics is None else extrinsics.to(prediction.depth)
            intrinsics = prediction.intrinsics if intrinsics is None else intrinsics.to(prediction.depth)
            depth = prediction.depth if depth is None else depth.to(prediction.depth)
            # Stop-gradient cameras: rendering losses train depth and appearance, only camera
            # losses train the camera head. Otherwise the rendering loss pulls the predicted
            # field of view to a degenerate extreme (docs/model.md, "Geometry").
            world_points = unproject_depth(depth, extrinsics.detach(), intrinsics.detach())
            scales = scene_scale(depth)
            sizes = [voxel_size] * depth.shape[0]
            if footprint_scale is not None:
                views = slice(None) if fuse_views is None else fuse_views
                height, width = depth.shape[-2:]
                sizes = [
                    footprint_voxel_sizes(
                        pixel_footprint(world_points[b].detach().reshape(-1, 3), extrinsics[b, views].detach(),
                                        intrinsics[b, views].detach(), (width, height)).reshape(depth.shape[1:]),
                        footprint_scale, scales[b],
                    )
                    for b in range(depth.shape[0])
                ]
            scenes = [
                self.fuse_scene(world_points[b], prediction.params[b], prediction.confidence[b], scales[b], sizes[b],
                                fuse_views, None if fuse_pixels is None else fuse_pixels[b], footprint_scale is not None)
                for b in range(depth.shape[0])
            ]
        pixel_gaussians, gaussians, counts = (list(column) for column in zip(*scenes))
        output = Lumos3DOutput(
            pose_enc=prediction.pose_enc_list[-1], pose_enc_list=prediction.pose_enc_list, extrinsics=extrinsics,
            intrinsics=intrinsics, depth=depth, depth_conf=prediction.depth_conf, world_points=world_points,
            pixel_confidence=prediction.confidence, pixel_gaussians=pixel_gaussians, gaussians=gaussians,
            scene_scale=scales, counts=counts, appearance=prediction.appearance,
        )
        _require_finite_output(output)
        return output

    def forward(
        self, images: torch.Tensor, voxel_size: float | None = None, fuse_views: torch.Tensor | None = None
    ) -> Lumos3DOutput:
        """images [B, V, 3, H, W] in [0, 1], H and W multiples of the patch size -> Lumos3DOutput:
        `predict`, then `assemble` on the predicted cameras and depth."""
        return self.assemble(self.predict(images), voxel_size=voxel_size, fuse_views=fuse_views)


def _require_finite_output(output: Lumos3DOutput) -> None:
    hint = "the network produced NaN/Inf (corrupt weights or an unstable input?)"
    for name in ("pose_enc", "extrinsics", "intrinsics", "depth", "depth_conf", "pixel_confidence"):
        require_finite(f"model output {name}", getattr(output, name), hint)
    for scene, gaussians in enumerate(output.gaussians):
        gaussians.require_finite(f"model output gaussians[{scene}]")
    for scene, gaussians in enumerate(output.pixel_gaussians):
        gaussians.require_finite(f"model output pixel_gaussians[{scene}]")
    if output.appearance is not None:
        output.appearance.require_finite("model output appearance")


def build_model(architecture: str | Architecture = DEFAULT_ARCHITECTURE, seed: int | None = None) -> Lumos3D:
    """A network with **random** weights (for training, tests and benchmarks — not inference;
    use `load_model` for trained weights). `seed` makes the initialisation reproducible."""
    architecture = get_architecture(architecture) if isinstance(architecture, str) else architecture
    if seed is None:
        model = Lumos3D(architecture)
    else:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            model = Lumos3D(architecture)
    model.provenance = {"weights": "random", "seed": seed}
    logger.info("built architecture '%s' with random weights (untrained: not for inference)", architecture.name)
    return model
