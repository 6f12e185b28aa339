"""The restoration operator of a scene: a 3x3 colour matrix, an optional per-view local gain
grid and a per-channel monotone curve, all in linear light.

Order: sRGB -> linear -> matrix -> local gain -> curve -> (near-clipped input: its own
chromaticity) -> clip to [0, 1] -> sRGB. It mirrors a
camera's pipeline, where white balance and colour correction act on linear sensor values and
the tone curve comes last: the matrix removes a colour cast while the values are still
proportional to light (a cast is a per-channel gain there, not in sRGB); the local gain, a
change of illumination across the frame, multiplies light before any tone mapping; the curve
then sets exposure and tone on colour-balanced channels, and being last it alone decides how
highlights roll off (the part over-exposure needs). Every stage is the identity at
initialisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear
from lumos3d_cli.model.appearance.clipped_highlights import keep_input_chromaticity
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS, MAX_GAIN, apply_curve, bound_slopes, curve_knots
from lumos3d_cli.model.appearance.local_correction import LOCAL_MAX_STOPS, bound_log_gain, upsample_log_gain

_PIXELS_PER_BAND = 1 << 22  # pixels of all images together restored at once (one band of 4 M: 0.4 GB of temporaries)
MATRIX_BOUND = 0.5  # every entry within +-0.5 of the identity's: casts, not channel swaps


def bound_matrix(raw: torch.Tensor, bound: float = MATRIX_BOUND) -> torch.Tensor:
    """[..., 3, 3] unbounded -> identity + bound * tanh(raw) (the identity where raw = 0)."""
    return torch.eye(3, dtype=raw.dtype, device=raw.device) + bound * torch.tanh(raw)


@dataclass
class AppearanceOperator:
    """The operators of B scenes of V views (activated, bounded values).

    curve_slopes [B, 3, K-1] in [1/MAX_GAIN, MAX_GAIN]; matrix [B, 3, 3] (rows: output
    channels); local_log2_gain [B, V, C, g, g] with C = 1 (one gain for all channels) or 3, or
    None (no local correction). Knots: `curve.curve_knots(K)`.
    """

    curve_slopes: torch.Tensor
    matrix: torch.Tensor
    local_log2_gain: torch.Tensor | None = None

    @staticmethod
    def from_raw(curve_raw: torch.Tensor, matrix_raw: torch.Tensor, local_raw: torch.Tensor | None = None) -> AppearanceOperator:
        """Unbounded parameters (a head's output, or a fit's variables) -> bounded operator.
        curve_raw [B, 3, K-1], matrix_raw [B, 3, 3], local_raw [B, V, C, g, g] or None."""
        local = None if local_raw is None else bound_log_gain(local_raw, LOCAL_MAX_STOPS)
        return AppearanceOperator(bound_slopes(curve_raw, MAX_GAIN), bound_matrix(matrix_raw), local)

    @staticmethod
    def identity(batch: int = 1, views: int | None = None, knots: int = CURVE_KNOTS, local_channels: int = 1,
                 grid_size: int = 8, device: torch.device | str | None = None) -> AppearanceOperator:
        """The operator that returns its input (up to clipping); with a local grid when `views`."""
        local = None if views is None else torch.zeros(batch, views, local_channels, grid_size, grid_size, device=device)
        return AppearanceOperator(
            torch.ones(batch, 3, knots - 1, device=device), torch.eye(3, device=device).expand(batch, 3, 3).clone(), local
        )

    @property
    def batch(self) -> int:
        return int(self.curve_slopes.shape[0])

    @property
    def knots(self) -> torch.Tensor:
        """[K] knot positions in linear light."""
        return curve_knots(self.curve_slopes.shape[-1] + 1).to(self.curve_slopes.device)

    def scene(self, index: int) -> AppearanceOperator:
        """The operator of one scene (B = 1)."""
        local = None if self.local_log2_gain is None else self.local_log2_gain[index : index + 1]
        return AppearanceOperator(self.curve_slopes[index : index + 1], self.matrix[index : index + 1], local)

    def views(self, selected: torch.Tensor | slice) -> AppearanceOperator:
        """The same scene operators restricted to some views' local grids."""
        local = None if self.local_log2_gain is None else self.local_log2_gain[:, selected]
        return AppearanceOperator(self.curve_slopes, self.matrix, local)

    def detach(self) -> AppearanceOperator:
        local = None if self.local_log2_gain is None else self.local_log2_gain.detach()
        return AppearanceOperator(self.curve_slopes.detach(), self.matrix.detach(), local)

    def with_gain(self, log2_gain: torch.Tensor) -> AppearanceOperator:
        """The same operators followed by one gain per scene in linear light, log2_gain [B] stops
        (`exposure_prior`). The curve is linear in its slopes and starts at 0, so scaling every
        slope is exactly a gain on its output; the slopes may then leave [1/MAX_GAIN, MAX_GAIN]."""
        gain = torch.exp2(log2_gain.to(self.curve_slopes)).reshape(-1, 1, 1)
        return AppearanceOperator(self.curve_slopes * gain, self.matrix, self.local_log2_gain)

    def require_finite(self, name: str = "appearance operator") -> None:
        hint = "the illumination head produced NaN/Inf (corrupt weights or an unstable input?)"
        require_finite(f"{name} curve", self.curve_slopes, hint)
        require_finite(f"{name} matrix", self.matrix, hint)
        if self.local_log2_gain is not None:
            require_finite(f"{name} local gain", self.local_log2_gain, hint)

    def apply_linear(self, linear: torch.Tensor) -> torch.Tensor:
        """linear [B, V, 3, H, W] -> restored linear light [B, V, 3, H, W] float32 (not clipped).

        The local grid must have V views (or be None); it is upsampled to H x W. Where the input
        is clipped or nearly so, the result takes the input's chromaticity at its own luminance
        (`clipped_highlights`): clipped input holds no colour for the operator to restore.
        """
        batch, views, _, height, width = linear.shape
        if batch != self.batch:
            raise ValueError(f"operator holds {self.batch} scenes, images {batch}")
        with torch.autocast(linear.device.type, enabled=False):
            gain = None
            if self.local_log2_gain is not None:
                if self.local_log2_gain.shape[1] != views:
                    raise ValueError(f"operator has local grids for {self.local_log2_gain.shape[1]} views, images {views}")
                grid = self.local_log2_gain.flatten(0, 1)  # [B*V, C, g, g]
                gain = torch.exp2(upsample_log_gain(grid, height, width)).reshape(batch, views, -1, height, width)
            # Every step below is per pixel: done in bands of rows, so that a full-resolution photo
            # (27 MP) does not hold a dozen full-size temporaries at once (3 GB of them a view)
            rows = max(1, _PIXELS_PER_BAND // max(1, batch * views * width))
            bands = [self._apply_to_rows(linear[..., top:top + rows, :], None if gain is None else gain[..., top:top + rows, :])
                     for top in range(0, height, rows)]
            return bands[0] if len(bands) == 1 else torch.cat(bands, dim=-2)

    def _apply_to_rows(self, linear: torch.Tensor, gain: torch.Tensor | None) -> torch.Tensor:
        """`apply_linear` of rows of the images, linear [B, V, 3, h, W], with the local gain of
        those rows, gain [B, V, C, h, W] (None: no local grid)."""
        # Negative values after the matrix are light that does not exist: clamp them to black.
        mixed = torch.einsum("bij,bvjhw->bvihw", self.matrix.float(), linear.float()).clamp_min(0.0)
        if gain is not None:
            mixed = mixed * gain
        # near-clipped photo pixels keep their own chromaticity (model/appearance/clipped_highlights.py)
        return keep_input_chromaticity(linear.float(), apply_curve(mixed, self.curve_slopes, self.knots))

    def apply(self, images: torch.Tensor) -> torch.Tensor:
        """images [B, V, 3, H, W] sRGB in [0, 1] -> restored sRGB [B, V, 3, H, W] in [0, 1], float32."""
        linear = srgb_to_linear(images.float().clamp(0.0, 1.0))
        return linear_to_srgb(self.apply_linear(linear).clamp(0.0, 1.0))
