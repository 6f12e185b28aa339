"""Image-quality metrics: PSNR on [0, 1]; PSNR after matching the reference's mean grey level
("GT-mean" PSNR); SSIM with an 11x11 Gaussian window (sigma 1.5),
K1 = 0.01, K2 = 0.03, population covariances, reflected borders cropped before averaging (the
settings of scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)`, which the tests use as the oracle); sharpness, the high-frequency
energy of an image over its reference's; LPIPS (losses/lpips.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from lumos3d_cli.eval.tone_curve import auto_gamma_array
from lumos3d_cli.io.colour import luma, luminance
from lumos3d_cli.losses.ssim import ssim_map_mean


def _flatten(images: torch.Tensor) -> torch.Tensor:
    if images.dim() < 3 or images.shape[-3] != 3:
        raise ValueError(f"expected images [..., 3, H, W], got {tuple(images.shape)}")
    return images.reshape(-1, *images.shape[-3:]).double()


def _pair(images: torch.Tensor, references: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Both [N, 3, H, W] float64; ValueError unless they are floating-point images of one shape
    (broadcasting would score a batch against one reference, or one row against a whole image)."""
    if images.shape != references.shape:
        raise ValueError(f"images {tuple(images.shape)} and references {tuple(references.shape)} differ in shape; "
                         "score images of their references' size")
    for name, tensor in (("images", images), ("references", references)):
        if not tensor.is_floating_point():
            raise ValueError(f"{name} are {tensor.dtype}; the metrics take floating-point values in [0, 1]")
    return _flatten(images), _flatten(references)


def psnr(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] -> [...] PSNR in dB (inf for identical images)."""
    ours, theirs = _pair(images, references)
    mse = ((ours - theirs) ** 2).mean(dim=(1, 2, 3))
    return (10 * torch.log10(1.0 / mse)).reshape(images.shape[:-3])


def psnr_gt_mean(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] -> [...] PSNR in dB after scaling each image by its reference's mean
    grey level over its own (then clipping to [0, 1]): the "GT-mean" PSNR that low-light
    enhancement papers report beside PSNR (LLFlow, Retinexformer). It leaves out one number, the
    overall exposure, which the reference fixes by the photographer's choice and a dark photo
    does not reveal; what remains scores colour, contrast and detail. An image with no light
    (mean grey 0) is scored as it is; against a reference with no light the score is NaN (scaled
    to black, any image would match it perfectly).
    """
    ours, theirs = _pair(images, references)
    our_grey = luma(ours).mean(dim=(1, 2, 3))  # OpenCV's grey, as the GT-mean protocol uses it
    their_grey = luma(theirs).mean(dim=(1, 2, 3))
    scale = torch.where(our_grey > 0, their_grey / our_grey.clamp_min(1e-12), torch.ones_like(our_grey))
    matched = (ours * scale[:, None, None, None]).clamp(0.0, 1.0)
    scores = psnr(matched, theirs)
    return torch.where(their_grey > 0, scores, torch.full_like(scores, math.nan)).reshape(images.shape[:-3])


def ssim(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] (H, W > 11) -> [...] mean SSIM over channels and pixels, in float64
    (the training loss's definition, losses/ssim.py, so that training optimises what is reported)."""
    a, b = _pair(images, references)
    return ssim_map_mean(a, b).reshape(images.shape[:-3])


def auto_gamma(images: torch.Tensor, target_mean: float = 0.45) -> torch.Tensor:
    """The blind no-learning baseline: per image, x^g with g = log(target) / log(mean(x)), so the
    mean of the sRGB values goes to about `target`. images [..., 3, H, W] in [0, 1]
    (`eval.tone_curve.auto_gamma_array`, on the CPU)."""
    values = images.detach().cpu()
    if values.dtype not in (torch.float16, torch.float32, torch.float64):  # bfloat16 has no numpy dtype
        values = values.float()
    corrected = auto_gamma_array(values.numpy(), target_mean)
    return torch.from_numpy(corrected).to(device=images.device, dtype=images.dtype)


SHARPNESS_SIGMAS = (0.7, 2.0)  # the band of a difference of Gaussians: pixel-scale detail, not shading


def _difference_of_gaussians(luminance: np.ndarray) -> np.ndarray:
    """[H, W] float64 -> G(sigma 0.7) - G(sigma 2.0), kernels truncated at 4 sigma, edges repeated
    (scikit-image's `difference_of_gaussians` defaults, which the tests use as the oracle)."""
    blurred = [cv2.GaussianBlur(luminance, (2 * int(4 * s + 0.5) + 1,) * 2, s, borderType=cv2.BORDER_REPLICATE)
               for s in SHARPNESS_SIGMAS]
    return blurred[0] - blurred[1]


def sharpness(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] -> [...] the mean absolute difference of Gaussians (sigma 0.7 and
    2.0) of each image's luminance over its reference's, after matching the image's luminance mean
    and deviation to the reference's (so exposure and contrast do not count, only detail).

    1 is as sharp as the reference; a blur scores below 1, noise or ringing above. A flat image
    scores 0; a flat reference gives NaN (nothing to compare against).
    """
    ours, theirs = (luminance(batch)[:, 0].numpy() for batch in _pair(images, references))  # Rec. 709 weights
    ratios = []
    for image, reference in zip(ours, theirs):
        spread = image.std()
        matched = (image - image.mean()) * (reference.std() / spread if spread > 1e-12 else 0.0) + reference.mean()
        detail = np.abs(_difference_of_gaussians(reference)).mean()
        ratios.append(np.abs(_difference_of_gaussians(matched)).mean() / detail if detail > 1e-12 else math.nan)
    return torch.tensor(ratios, dtype=torch.float64).reshape(images.shape[:-3])
