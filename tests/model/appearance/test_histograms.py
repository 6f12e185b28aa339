import numpy as np
import torch

from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.model.appearance.histograms import HISTOGRAM_BINS, HISTOGRAM_STOPS, log_histograms


def test_matches_numpy_histogram_of_log_linear_light():
    images = torch.rand(1, 2, 3, 30, 40, generator=torch.Generator().manual_seed(0)) ** 3
    histograms = log_histograms(images)
    assert histograms.shape == (1, 2, 3, HISTOGRAM_BINS)
    linear = srgb_to_linear(images.double().numpy())
    for view in range(2):
        for channel in range(3):
            logs = np.clip(np.log2(np.maximum(linear[0, view, channel], 2.0**-HISTOGRAM_STOPS)), -HISTOGRAM_STOPS, -1e-9)
            expected, _ = np.histogram(logs, bins=HISTOGRAM_BINS, range=(-HISTOGRAM_STOPS, 0))
            np.testing.assert_allclose(histograms[0, view, channel].numpy(), expected / logs.size, atol=1e-6)


def test_black_and_saturated_frames_fill_the_end_bins():
    frames = torch.stack((torch.zeros(3, 8, 8), torch.ones(3, 8, 8)))[None]
    histograms = log_histograms(frames)
    assert bool(torch.isfinite(histograms).all())
    assert bool((histograms[0, 0, :, 0] == 1).all()) and bool((histograms[0, 1, :, -1] == 1).all())
