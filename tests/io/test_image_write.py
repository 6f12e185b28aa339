import numpy as np
import pytest

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.image_write import write_exr, write_image
from lumos3d_cli.io.images import read_image


@pytest.mark.parametrize("bit_depth", [8, 16])
def test_png_round_trip_is_exact_on_the_code_grid(tmp_path, bit_depth):
    scale = (1 << bit_depth) - 1
    codes = np.random.default_rng(0).integers(0, scale + 1, (9, 11, 3))
    write_image(tmp_path / "a.png", (codes / scale).astype(np.float32), bit_depth=bit_depth)
    image = read_image(tmp_path / "a.png")
    assert image.bit_depth == bit_depth
    np.testing.assert_array_equal(np.round(image.pixels * scale), codes)


def test_exr_round_trip(tmp_path):
    linear = np.random.default_rng(1).uniform(0, 8, (5, 4, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", linear, half=False)
    np.testing.assert_array_equal(read_image(tmp_path / "a.exr").pixels, linear)


def test_writes_leave_no_temporary_files(tmp_path):
    write_image(tmp_path / "a.jpg", np.zeros((4, 4, 3), np.float32))
    assert [p.name for p in tmp_path.iterdir()] == ["a.jpg"]


def test_refuses_non_finite_pixels_and_bad_formats(tmp_path):
    pixels = np.zeros((4, 4, 3), np.float32)
    pixels[0, 0, 0] = np.nan
    with pytest.raises(NonFiniteError, match="1 of 48 values are NaN or Inf"):
        write_image(tmp_path / "a.png", pixels)
    with pytest.raises(InputError, match="JPEG holds 8 bits only"):
        write_image(tmp_path / "a.jpg", np.zeros((4, 4, 3), np.float32), bit_depth=16)
    with pytest.raises(InputError, match="cannot write '.gif'"):
        write_image(tmp_path / "a.gif", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(InputError, match="1000001x1 pixels; a PNG written here holds at most 1,000,000 a side"):
        write_image(tmp_path / "a.png", np.zeros((1, 1_000_001, 3), np.float32))  # OSError from OpenCV's encoder
    assert not any(tmp_path.iterdir())
