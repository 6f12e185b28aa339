import pytest
import torch

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.model.preprocess import network_size, prepare_images


def test_resize_mode_sizes():
    assert network_size(1000, 750, 518, 14) == (518, 392, 392)
    assert network_size(750, 1000, 518, 14) == (392, 518, 518)  # portrait keeps its whole height
    assert network_size(28, 28, 224, 14) == (224, 224, 224)  # small images are enlarged
    assert network_size(4000, 10, 224, 14) == (224, 14, 14)  # at least one patch


def test_crop_mode_follows_vggt():
    assert network_size(1000, 750, 518, 14, "crop") == (518, 392, 392)
    assert network_size(750, 1000, 518, 14, "crop") == (518, 518, 686)  # 686 rows, centre 518 kept
    with pytest.raises(InputError, match="mode"):
        network_size(10, 10, 518, 14, "stretch")


def _project(intrinsics: torch.Tensor, point: torch.Tensor) -> torch.Tensor:
    pixel = intrinsics @ point
    return pixel[:2] / pixel[2]


@pytest.mark.parametrize("mode", ["resize", "crop"])
def test_intrinsics_map_pixels_exactly_between_original_and_network_images(mode):
    images = torch.rand(2, 3, 300, 200, dtype=torch.float64)  # portrait, so crop mode crops
    prepared = prepare_images(images, 224, 14, mode)
    width, height = prepared.network_size
    assert prepared.images.shape == (2, 3, height, width)
    assert height % 14 == 0 and width % 14 == 0
    original = torch.tensor([[250.0, 0, 100], [0, 260, 150], [0, 0, 1]], dtype=torch.float64)
    network = prepared.intrinsics_to_network(original)
    point = torch.tensor([0.3, -0.2, 2.0], dtype=torch.float64)
    (sx, sy), (ox, oy) = prepared.scale, prepared.offset
    expected = _project(original, point) * torch.tensor([sx, sy], dtype=torch.float64) - torch.tensor([ox, oy], dtype=torch.float64)
    torch.testing.assert_close(_project(network, point), expected)
    torch.testing.assert_close(prepared.intrinsics_to_original(network), original)
    # the original image's centre maps to the network image's centre
    centre = network @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    if mode == "resize":
        torch.testing.assert_close(centre[:2], torch.tensor([width / 2, height / 2], dtype=torch.float64))


def test_values_stay_in_range_and_sizes_that_fit_are_untouched():
    images = torch.zeros(1, 3, 40, 40)
    images[..., ::2, :] = 1.0  # high-contrast stripes make bicubic overshoot
    prepared = prepare_images(images, 56, 14)
    assert prepared.images.min() >= 0 and prepared.images.max() <= 1
    exact = torch.rand(3, 56, 42)
    assert torch.equal(prepare_images(exact, 56, 14).images, exact)


def test_bad_inputs_are_refused():
    with pytest.raises(InputError):
        prepare_images(torch.zeros(3, 4, 4, dtype=torch.uint8), 56, 14)
    with pytest.raises(InputError):
        prepare_images(torch.zeros(4, 5, 5), 56, 14)
    for bad in (float("nan"), float("inf")):
        images = torch.rand(3, 20, 20)
        images[1, 3, 4] = bad
        with pytest.raises(NonFiniteError, match="images"):
            prepare_images(images, 56, 14)
    for size, patch, name in ((0, 14, "image_size"), (-5, 14, "image_size"), (10, 14, "image_size"),
                              (56, 0, "patch_size"), (56.0, 14, "image_size")):
        with pytest.raises(InputError, match=f"^{name} "):
            prepare_images(torch.rand(3, 20, 20), size, patch)


def test_numpy_integers_are_sizes_too():
    import numpy as np

    assert prepare_images(torch.rand(3, 40, 60), np.int64(56), np.int32(14)).network_size == (56, 42)


def test_bicubic_overshoot_is_clamped_and_values_outside_the_unit_range_refused():
    """Bicubic overshoots at a black/white edge: clamped. Images outside [0, 1] (8-bit codes not
    divided by 255, a normalised batch) were clamped too, into a white frame, silently: refused."""
    edge = torch.zeros(3, 42, 56)
    edge[..., 28:] = 1.0
    prepared = prepare_images(edge, 28, 14)
    assert 0.0 <= float(prepared.images.min()) and float(prepared.images.max()) <= 1.0
    for images, message in ((torch.full((3, 40, 40), 255.0), r"values from 255 to 255; give sRGB in \[0, 1\] \(8-bit codes"),
                            (torch.full((3, 40, 40), -0.5), r"values from -0.5 to -0.5; give sRGB in \[0, 1\]$"),
                            (torch.zeros(0, 3, 40, 40), r"an empty batch \(0, 3, 40, 40\)")):
        with pytest.raises(InputError, match=message):
            prepare_images(images, 56, 14)
    prepare_images(torch.full((3, 40, 40), 1.0005), 56, 14)  # rounding in a colour conversion: accepted


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float64])
def test_every_floating_type_is_prepared_in_its_own_type(dtype):
    images = torch.rand(2, 3, 37, 51, generator=torch.Generator().manual_seed(0))
    expected = prepare_images(images.to(dtype).float(), 56, 14).images
    prepared = prepare_images(images.to(dtype), 56, 14).images
    assert prepared.dtype == dtype
    torch.testing.assert_close(prepared.float(), expected.to(dtype).float())
