"""The rasterizer's depth sort (kernels/radix_sort.py through binning.front_to_back) against
numpy's stable argsort: the same order, ties broken by index, for every thread count."""

import numpy as np
import pytest

from lumos3d_cli.render.kernels.binning import front_to_back
from lumos3d_cli.render.kernels.radix_sort import stable_argsort_uint32


def _depths_with_ties(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    depths = (rng.random(n) * 50).astype(np.float32)
    depths[::7] = np.round(depths[::7], 1)  # many exact ties
    depths[::11] *= -1  # behind the camera: negative keys sort first
    extremes = np.array([0.0, -0.0, 1e-38, 3e38], dtype=np.float32)[:n]
    depths[: len(extremes)] = extremes
    return depths


@pytest.mark.parametrize("threads", [1, 2, 3])
@pytest.mark.parametrize("n", [0, 1, 1000, 200_003])
def test_front_to_back_matches_numpys_stable_argsort(n, threads):
    depths = _depths_with_ties(n, seed=n)
    radii = np.random.default_rng(n + 1).integers(0, 4, size=(n, 2)).astype(np.int32)
    drawn = np.flatnonzero((radii[:, 0] > 0) | (radii[:, 1] > 0))
    # -0.0 and 0.0 are one depth: numpy compares them equal, so its stable sort keeps index order.
    expected = drawn[np.argsort(depths[drawn], kind="stable")]
    got = front_to_back(radii, depths, threads)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, expected)
    # float64 depths take numpy's own sort: the same order.
    np.testing.assert_array_equal(front_to_back(radii, depths.astype(np.float64), threads), expected)


def test_radix_sort_is_stable_on_equal_keys_and_orders_every_bit():
    keys = np.array([5, 2**32 - 1, 5, 0, 2**31, 5, 2**11, 2**22, 1], dtype=np.uint32)
    order = np.array([8, 7, 6, 5, 4, 3, 2, 1, 0])  # not index order: stability keeps this order for ties
    got = stable_argsort_uint32(keys, order, threads=2)
    assert list(keys[got]) == sorted(keys.tolist())
    assert [i for i in got if keys[i] == 5] == [5, 2, 0]
    assert order.tolist() == [8, 7, 6, 5, 4, 3, 2, 1, 0]  # the input is not sorted in place
