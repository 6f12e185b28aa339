"""The illumination head: aggregator tokens of all views (and the photos' log histograms) ->
one restoration operator per scene plus a local gain grid per view."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from lumos3d_cli.model.appearance.curve import CURVE_KNOTS
from lumos3d_cli.model.appearance.histograms import HISTOGRAM_BINS, log_histograms
from lumos3d_cli.model.appearance.local_correction import LOCAL_GRID_SIZE
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.layers.mlp import Mlp


class IlluminationHead(nn.Module):
    """tokens [B, V, P, D] of one aggregator layer, images [B, V, 3, H, W] -> AppearanceOperator.

    Scene operator: each view's patch tokens are averaged and normalised, its per-channel log
    histograms appended, an MLP maps that to a view feature; the mean over views (so 1 view and
    64 views give features of the same scale, in any view order) goes through a linear layer to
    the curve and matrix parameters. Local grid: the patch tokens, average-pooled to
    grid_size x grid_size cells, with the scene feature appended, through a 1x1 MLP to C log2
    gains per cell. The output layers start at zero, so an untrained head is the identity.

    D = token_dim (twice the aggregator width); histogram_bins = 0 leaves the histograms out;
    local_channels = 0 leaves the local correction out (local_log2_gain None).
    """

    def __init__(
        self,
        token_dim: int,
        patch_start_index: int,
        patch_size: int,
        hidden: int = 128,
        knots: int = CURVE_KNOTS,
        histogram_bins: int = HISTOGRAM_BINS,
        local_channels: int = 1,
        grid_size: int = LOCAL_GRID_SIZE,
    ):
        super().__init__()
        self.patch_start_index = patch_start_index
        self.patch_size = patch_size
        self.knots = knots
        self.histogram_bins = histogram_bins
        self.local_channels = local_channels
        self.grid_size = grid_size
        self.token_norm = nn.LayerNorm(token_dim)
        self.view_mlp = Mlp(token_dim + 3 * histogram_bins, hidden, hidden)
        self.scene_norm = nn.LayerNorm(hidden)
        self.scene_out = nn.Linear(hidden, 3 * (knots - 1) + 9)
        nn.init.zeros_(self.scene_out.weight)
        nn.init.zeros_(self.scene_out.bias)
        if local_channels:
            self.local_mlp = nn.Sequential(
                nn.Conv2d(token_dim + hidden, hidden, kernel_size=1), nn.GELU(), nn.Conv2d(hidden, local_channels, kernel_size=1)
            )
            nn.init.zeros_(self.local_mlp[-1].weight)
            nn.init.zeros_(self.local_mlp[-1].bias)

    def forward(self, tokens: torch.Tensor, images: torch.Tensor) -> AppearanceOperator:
        """tokens [B, V, P, D], images [B, V, 3, H, W] sRGB in [0, 1] (the network images) ->
        operator with curve_slopes [B, 3, K-1], matrix [B, 3, 3], local_log2_gain [B, V, C, g, g].

        Runs in float32 whatever the enclosing autocast (the operator multiplies light by up to
        64: bf16's 8-bit mantissa would band it).
        """
        batch, views = tokens.shape[:2]
        grid_h, grid_w = images.shape[-2] // self.patch_size, images.shape[-1] // self.patch_size
        with torch.autocast(tokens.device.type, enabled=False):
            patches = self.token_norm(tokens[:, :, self.patch_start_index :].float())  # [B, V, h*w, D]
            features = patches.mean(dim=2)
            if self.histogram_bins:
                histograms = log_histograms(images, self.histogram_bins).flatten(2)  # [B, V, 3*bins]
                features = torch.cat((features, histograms), dim=-1)
            view_features = self.view_mlp(features)  # [B, V, hidden]
            scene_feature = self.scene_norm(view_features.mean(dim=1))  # [B, hidden]
            raw = self.scene_out(scene_feature)
            curve_raw = raw[:, : 3 * (self.knots - 1)].reshape(batch, 3, self.knots - 1)
            matrix_raw = raw[:, 3 * (self.knots - 1) :].reshape(batch, 3, 3)
            local_raw = None
            if self.local_channels:
                grid = patches.reshape(batch * views, grid_h, grid_w, -1).permute(0, 3, 1, 2)
                cells = F.adaptive_avg_pool2d(grid, self.grid_size)  # [B*V, D, g, g]
                context = scene_feature[:, None].expand(batch, views, -1).reshape(batch * views, -1, 1, 1)
                cells = torch.cat((cells, context.expand(-1, -1, self.grid_size, self.grid_size)), dim=1)
                local_raw = self.local_mlp(cells).reshape(batch, views, self.local_channels, self.grid_size, self.grid_size)
            return AppearanceOperator.from_raw(curve_raw, matrix_raw, local_raw)
