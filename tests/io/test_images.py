import logging
import re

import cv2
import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import torch

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.colour import linear_to_srgb
from lumos3d_cli.io.image_files import list_images, natural_sort_key
from lumos3d_cli.io.images import load_images, probe_image, read_image


def _write_oiio(path, pixels, fmt, **attributes):
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, fmt)
    for key, value in attributes.items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(pixels)
    out.close()


def test_natural_sort_orders_numbers_by_value(tmp_path):
    for name in ["10.jpg", "2.jpg", "1.jpg", "img_11.png", "img_9.png"]:
        cv2.imwrite(str(tmp_path / name), np.zeros((4, 4, 3), np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / ".hidden.jpg").write_bytes(b"")
    names = [p.name for p in list_images(tmp_path)]
    assert names == ["1.jpg", "2.jpg", "10.jpg", "img_9.png", "img_11.png"]
    assert sorted(["b10", "b2", "a"], key=natural_sort_key) == ["a", "b2", "b10"]


def test_8_bit_png_values_are_exact(tmp_path):
    pixels = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), pixels[..., ::-1])
    image = read_image(tmp_path / "a.png")
    assert image.encoding == "srgb" and image.bit_depth == 8 and image.pixels.dtype == np.float32
    np.testing.assert_array_equal(image.pixels, pixels.astype(np.float32) / 255)


def test_16_bit_png_keeps_all_bits(tmp_path):
    pixels = np.random.default_rng(1).integers(0, 65536, (6, 5, 3), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "a.png"), pixels[..., ::-1])
    image = read_image(tmp_path / "a.png")
    assert image.bit_depth == 16
    np.testing.assert_array_equal(np.round(image.pixels * 65535).astype(np.uint16), pixels)
    assert probe_image(tmp_path / "a.png").bit_depth == 16


def test_16_bit_tiff_and_webp(tmp_path):
    pixels16 = np.random.default_rng(2).integers(0, 65536, (4, 4, 3), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "a.tif"), pixels16[..., ::-1])
    np.testing.assert_array_equal(np.round(read_image(tmp_path / "a.tif").pixels * 65535), pixels16)
    cv2.imwrite(str(tmp_path / "b.webp"), np.full((8, 8, 3), 128, np.uint8), [cv2.IMWRITE_WEBP_QUALITY, 101])
    np.testing.assert_allclose(read_image(tmp_path / "b.webp").pixels, 128 / 255)


def test_grayscale_becomes_rgb_and_alpha_is_dropped(tmp_path):
    cv2.imwrite(str(tmp_path / "grey.png"), np.full((3, 4), 200, np.uint8))
    grey = read_image(tmp_path / "grey.png")
    assert grey.pixels.shape == (3, 4, 3)
    np.testing.assert_allclose(grey.pixels, 200 / 255)
    rgba = np.zeros((3, 4, 4), np.uint8)
    rgba[..., :3] = (10, 20, 30)  # BGR
    rgba[..., 3] = 0
    cv2.imwrite(str(tmp_path / "rgba.png"), rgba)
    image = read_image(tmp_path / "rgba.png")
    assert image.pixels.shape == (3, 4, 3)
    np.testing.assert_allclose(image.pixels[0, 0], np.array([30, 20, 10]) / 255)


def test_exif_orientation_is_applied(tmp_path):
    pixels = np.zeros((20, 40, 3), np.uint8)
    pixels[:, :20] = 255  # left half white in the stored (unrotated) image
    _write_oiio(tmp_path / "rotated.jpg", pixels, "uint8", Orientation=6)
    image = read_image(tmp_path / "rotated.jpg")
    # Orientation 6: the stored image must be rotated 90 degrees clockwise for display,
    # so its left half becomes the top half.
    assert image.pixels.shape == (40, 20, 3)
    assert image.pixels[:20].mean() > 0.95 and image.pixels[20:].mean() < 0.05
    header = probe_image(tmp_path / "rotated.jpg")
    assert (header.width, header.height) == (20, 40)


def test_exr_is_read_as_linear_float(tmp_path):
    pixels = np.random.default_rng(3).uniform(0, 4, (6, 5, 4)).astype(np.float32)
    _write_oiio(tmp_path / "a.exr", pixels, "float")
    image = read_image(tmp_path / "a.exr")
    assert image.encoding == "linear" and image.kind == "hdr"
    np.testing.assert_array_equal(image.pixels, pixels[..., :3])


def test_exr_with_nan_is_refused_with_the_count(tmp_path):
    pixels = np.ones((4, 4, 3), np.float32)
    pixels[0, 0, 0] = np.nan
    pixels[1, 1, 2] = np.inf
    _write_oiio(tmp_path / "bad.exr", pixels, "float")
    with pytest.raises(NonFiniteError, match=r"bad\.exr: 2 of 48 samples are NaN or Inf"):
        read_image(tmp_path / "bad.exr")


def test_radiance_hdr(tmp_path):
    pixels = np.full((4, 4, 3), 2.5, np.float32)
    _write_oiio(tmp_path / "a.hdr", pixels, "float")
    image = read_image(tmp_path / "a.hdr")
    np.testing.assert_allclose(image.pixels, 2.5, rtol=1e-2)


def test_a_photo_named_as_hdr_is_refused_not_encoded_twice(tmp_path):
    """OpenImageIO decodes by content: a JPEG named .exr was read as linear light, its mean 0.29
    where the photo's is 0.08."""
    cv2.imwrite(str(tmp_path / "a.jpg"), np.full((8, 8, 3), 80, np.uint8))
    (tmp_path / "a.exr").write_bytes((tmp_path / "a.jpg").read_bytes())
    for read in (read_image, probe_image):
        with pytest.raises(InputError, match=r"a\.exr: is a jpeg file, not OpenEXR; give it its own suffix"):
            read(tmp_path / "a.exr")
    _write_oiio(tmp_path / "b.exr", np.full((4, 4, 3), 0.5, np.float32), "float")
    (tmp_path / "b.hdr").write_bytes((tmp_path / "b.exr").read_bytes())  # an EXR named .hdr decodes as what it is
    np.testing.assert_allclose(read_image(tmp_path / "b.hdr").pixels, 0.5)


def test_a_truncated_raw_is_refused_in_one_line(shared_data, tmp_path, capfd):
    """LibRaw printed its own "Unexpected end of file" above the refusal."""
    data = (shared_data / "raw" / "Blackmagic.dng").read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: int(len(data) * 0.9)])
    with pytest.raises(InputError, match=r"cut\.dng: cannot decode camera RAW: the file is damaged or truncated"):
        read_image(tmp_path / "cut.dng")
    assert capfd.readouterr().err == ""


def test_float64_and_signed_tiffs_are_described_as_they_are_read(tmp_path):
    """`info` called a float64 TIFF 8-bit sRGB while it is read as 32-bit linear; an int16 TIFF was
    told to be saved "as 8- or 16-bit"."""
    cv2.imwrite(str(tmp_path / "double.tif"), np.full((4, 4, 3), 0.25, np.float64))
    header, image = probe_image(tmp_path / "double.tif"), read_image(tmp_path / "double.tif")
    assert (header.bit_depth, header.encoding) == (image.bit_depth, image.encoding) == (32, "linear")
    cv2.imwrite(str(tmp_path / "signed.tif"), np.full((4, 4, 3), 100, np.int16))
    with pytest.raises(InputError, match=r"signed\.tif: unsupported sample type int16; save it as unsigned 8- or 16-bit"):
        read_image(tmp_path / "signed.tif")


def test_camera_raw_is_linear_and_white_balanced(shared_data):
    path = shared_data / "raw" / "Blackmagic.dng"
    image = read_image(path)
    assert image.kind == "raw" and image.encoding == "linear" and image.bit_depth == 16
    # the DNG's default crop (DefaultCropOrigin 16, 8; DefaultCropSize 4096 x 2160 of 4128 x 2176):
    # uncropped, its last three columns were black and the two before them dark
    assert image.pixels.shape == (2160, 4096, 3) and image.pixels.dtype == np.float32
    assert image.pixels.min() >= 0 and image.pixels.max() <= 1
    assert image.pixels[:, -3:].mean() > 0.25 * image.pixels.mean()
    # Oracle: LibRaw's own sRGB-curve rendering of the same file must equal our linear output
    # encoded with the sRGB curve (up to LibRaw's 16-bit rounding and its toe approximation).
    with rawpy.imread(str(path)) as raw:
        reference = raw.postprocess(gamma=(2.4, 12.92), no_auto_bright=True, output_bps=16, use_camera_wb=True)
        crop = raw.sizes
    reference = reference[crop.crop_top_margin: crop.crop_top_margin + crop.crop_height,
                          crop.crop_left_margin: crop.crop_left_margin + crop.crop_width].astype(np.float32) / 65535
    assert np.abs(linear_to_srgb(image.pixels) - reference).mean() < 0.01
    # Linear data of a normally exposed photo sits far below its sRGB encoding.
    assert image.pixels.mean() < 0.5 * reference.mean()
    header = probe_image(path)
    assert (header.width, header.height, header.kind) == (4096, 2160, "raw")


def test_unsupported_raw_is_named(tmp_path):
    fake = tmp_path / "photo.cr2"
    fake.write_bytes(b"II*\x00" + bytes(200))
    with pytest.raises(InputError, match=r"photo\.cr2: unsupported camera RAW .*DNG"):
        read_image(fake)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("empty.jpg", b"", r"empty\.jpg: file is empty \(0 bytes\)"),
        ("text.jpg", b"this is not a jpeg", r"text\.jpg: cannot decode as JPG"),
        ("text.png", b"hello", r"text\.png: cannot decode as PNG"),
    ],
)
def test_bad_files_are_named(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError, match=message):
        read_image(tmp_path / name)


def test_truncated_jpeg_is_refused(tmp_path, buu):
    data = (buu / "low" / "1.JPG").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.jpg: cannot decode as JPG \(corrupt, truncated"):
        read_image(tmp_path / "cut.jpg")


def test_a_jpeg_with_corrupt_data_is_refused_and_libraries_print_nothing(tmp_path, buu, capfd, caplog):
    """Bytes zeroed mid-file: libjpeg decodes on, with shifted colours and garbage blocks in the
    lower half, and says so only on stderr (OpenCV returned the garbage as the photo)."""
    data = bytearray((buu / "low" / "1.JPG").read_bytes())
    middle = len(data) // 2
    data[middle: middle + 40] = bytes(40)
    (tmp_path / "damaged.jpg").write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"damaged\.jpg: the JPEG data is corrupt \(Corrupt JPEG data: premature end of "
                                         r"data segment\): the decoded image would hold garbage; replace the file"):
        read_image(tmp_path / "damaged.jpg")
    # padding before the end marker (an editor's zeros) decodes intact: a warning, not a refusal
    original = (buu / "low" / "1.JPG").read_bytes()
    (tmp_path / "padded.jpg").write_bytes(original[:-2] + bytes(6) + original[-2:])
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli.io.photo"):
        decoded = read_image(tmp_path / "padded.jpg")
    assert np.array_equal(decoded.pixels, read_image(buu / "low" / "1.JPG").pixels)
    assert re.search(r"padded.jpg: libjpeg reports \d extraneous bytes before marker 0xd9: padding", caplog.text)
    # bytes inserted into the image data of a JPEG without restart markers: libjpeg reports the same
    # kind of line ("26 extraneous bytes before marker 0xd9"), about image data it stopped decoding
    # early (a fifth to a half of the pixels garbage): refused
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:256, 0:256]
    picture = (np.stack([x, y, (x + y) // 2], -1) + rng.integers(0, 30, (256, 256, 3))).clip(0, 255).astype(np.uint8)
    encoded = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
    refused = 0
    for trial in range(12):
        damaged = bytearray(encoded)
        at = int(rng.integers(len(damaged) // 4, 3 * len(damaged) // 4))
        damaged[at:at] = rng.integers(1, 255, 3, dtype=np.uint8).tobytes()
        (tmp_path / "inserted.jpg").write_bytes(bytes(damaged))
        caplog.clear()
        try:
            read_image(tmp_path / "inserted.jpg")
        except InputError as error:
            assert "extraneous bytes before marker 0xd9" in str(error)
            refused += 1
        assert "padding" not in caplog.text
    assert refused >= 3
    (tmp_path / "broken.png").write_bytes(cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes()[:60])
    with pytest.raises(InputError, match=r"broken\.png: cannot decode as PNG"):
        read_image(tmp_path / "broken.png")
    assert read_image(buu / "low" / "1.JPG").pixels.shape == (375, 500, 3)
    assert "libpng" not in capfd.readouterr().err  # the one line above says it


def test_no_images_and_unsupported_types(tmp_path):
    with pytest.raises(InputError, match="folder holds no images"):
        list_images(tmp_path)
    (tmp_path / "images").mkdir()  # a scene folder in nerfstudio's layout: the photos one level down
    cv2.imwrite(str(tmp_path / "images" / "1.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError, match=r"folder holds no images .*; its subfolder images does: give that folder"):
        list_images(tmp_path)
    (tmp_path / "low").mkdir()
    cv2.imwrite(str(tmp_path / "low" / "1.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError, match=r"; its subfolders images, low do: give one of them"):
        list_images(tmp_path)
    (tmp_path / "low" / "1.png").unlink()
    (tmp_path / "images" / "1.png").unlink()
    with pytest.raises(InputError, match="no such file or folder"):
        list_images(tmp_path / "missing")
    (tmp_path / "a.gif").write_bytes(b"GIF89a")
    with pytest.raises(InputError, match=r"a\.gif: unsupported file type '\.gif'"):
        list_images([tmp_path / "a.gif"])
    with pytest.raises(InputError, match="no input images given"):
        list_images([])


def test_load_images_of_a_real_scene(shared_data):
    batch = load_images(shared_data / "scenes" / "llff_fern" / "images")
    assert batch.images.shape == (20, 3, 384, 512) and batch.images.dtype == torch.float32
    assert 0 <= batch.images.min() and batch.images.max() <= 1
    assert [p.name for p in batch.paths][:3] == ["000.jpg", "001.jpg", "002.jpg"]
    reference = cv2.imread(str(batch.paths[5]))[..., ::-1].astype(np.float32) / 255
    np.testing.assert_array_equal(batch.images[5].permute(1, 2, 0).numpy(), reference)


def test_mixed_sizes_are_stretched_to_the_most_common_and_keep_their_own_sizes(tmp_path, caplog):
    cv2.imwrite(str(tmp_path / "1.png"), np.full((20, 30, 3), 100, np.uint8))
    cv2.imwrite(str(tmp_path / "2.png"), np.full((20, 30, 3), 100, np.uint8))
    left_right = np.zeros((40, 20, 3), np.uint8)  # a portrait photo: dark left half, bright right half
    left_right[:, 10:] = 200
    cv2.imwrite(str(tmp_path / "3.png"), left_right)
    with caplog.at_level(logging.INFO, logger="lumos3d_cli.io.images"):
        batch = load_images(tmp_path)
    assert batch.images.shape == (3, 3, 20, 30) and batch.size == (30, 20) and batch.mixed_sizes
    assert batch.original_sizes == [(30, 20), (30, 20), (20, 40)]
    assert "stretched to 30x20: 3.png" in caplog.text
    np.testing.assert_allclose(batch.images[0].numpy(), 100 / 255, atol=1e-6)
    # stretched: the boundary between the halves stays in the middle of the 30 columns
    np.testing.assert_allclose(batch.images[2, :, :, :14].numpy(), 0, atol=1e-6)
    np.testing.assert_allclose(batch.images[2, :, :, 16:].numpy(), 200 / 255, atol=1e-6)
    photo = batch.photo(2)  # back at its own size
    assert photo.shape == (3, 40, 20)
    np.testing.assert_allclose(photo[:, :, :9].numpy(), 0, atol=1e-6)
    np.testing.assert_allclose(photo[:, :, 11:].numpy(), 200 / 255, atol=1e-6)
    assert torch.equal(batch.photo(0), batch.images[0])
    assert torch.equal(batch.photo(2), torch.from_numpy(cv2.imread(str(tmp_path / "3.png"))[..., ::-1].copy()).permute(2, 0, 1) / 255.0)


def test_photos_of_one_size_are_not_mixed(tmp_path):
    for name in ("1.png", "2.png"):
        cv2.imwrite(str(tmp_path / name), np.full((20, 30, 3), 100, np.uint8))
    assert not load_images(tmp_path).mixed_sizes


def test_linear_sources_are_encoded_once_and_clipped(tmp_path, caplog):
    _write_oiio(tmp_path / "a.exr", np.full((4, 4, 3), 0.18, np.float32), "float")
    _write_oiio(tmp_path / "b.exr", np.full((4, 4, 3), 3.0, np.float32), "float")
    _write_oiio(tmp_path / "c.exr", np.full((4, 4, 3), -0.5, np.float32), "float")
    batch = load_images(tmp_path)
    np.testing.assert_allclose(batch.images[0].numpy(), linear_to_srgb(np.float32(0.18)), atol=1e-6)
    np.testing.assert_allclose(batch.images[1].numpy(), 1.0)
    np.testing.assert_allclose(batch.images[2].numpy(), 0.0)
    assert "b.exr: 100.0% of linear samples exceed 1.0 and were clipped" in caplog.text
    assert "c.exr: 100.0% of linear samples are negative and were clipped" in caplog.text  # clipped silently before
    assert "a.exr" not in caplog.text


def test_transparent_pixels_are_warned_of_since_alpha_is_ignored(tmp_path, caplog):
    rgba = np.zeros((8, 10, 4), np.uint8)
    rgba[..., 1] = 200
    rgba[..., 3] = 255
    cv2.imwrite(str(tmp_path / "opaque.png"), rgba)
    rgba[:, :5, 3] = 0  # the left half hidden
    cv2.imwrite(str(tmp_path / "half.png"), rgba)
    cv2.imwrite(str(tmp_path / "rgb.png"), rgba[..., :3])
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli.io.photo"):
        for name in ("opaque.png", "rgb.png"):
            assert read_image(tmp_path / name).pixels.shape == (8, 10, 3)
        assert caplog.text == ""
        half = read_image(tmp_path / "half.png").pixels
    assert "half.png: 50.0 % of its pixels are transparent or partly so; alpha is ignored" in caplog.text
    assert np.allclose(half[..., 1], 200 / 255)  # the colour under the hidden pixels, as documented


@pytest.mark.parametrize("name, channels, dtype", [
    ("rgba.png", 4, "uint8"), ("rgba16.png", 4, "uint16"), ("ga.png", 2, "uint8"), ("ga16.png", 2, "uint16"),
    ("rgba.tif", 4, "uint8"), ("rgba16.tif", 4, "uint16"), ("rgba.webp", 4, "uint8"),
])
def test_a_photo_with_alpha_reads_as_opencvs_colour_decoding_gives_it(tmp_path, name, channels, dtype):
    """One decode with alpha kept, its colour as OpenCV's own colour decoding (the oracle) gives it."""
    pixels = (np.random.default_rng(0).random((9, 11, channels)) * np.iinfo(dtype).max).astype(dtype)
    path = tmp_path / name
    if name.endswith(".webp"):
        assert cv2.imwrite(str(path), pixels, [cv2.IMWRITE_WEBP_QUALITY, 101])
    else:
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), oiio.ImageSpec(11, 9, channels, dtype))
        out.write_image(pixels)
        out.close()
    colour = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)[..., ::-1]
    expected = colour.astype(np.float32) / np.iinfo(colour.dtype).max
    np.testing.assert_array_equal(read_image(path).pixels, expected)


def test_colour_profiles_other_than_srgb_are_named_and_a_linear_png_is_read_as_linear(tmp_path, caplog):
    """An Adobe RGB JPEG was read as sRGB without a word (17 % less chroma); a 16-bit PNG whose gAMA
    says linear light was read as sRGB codes (mean 0.009 where viewers show 0.083)."""
    from lumos3d_cli.io import photo
    from lumos3d_cli.io.images import to_srgb

    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    for name, description in (("adobe.jpg", "Adobe RGB (1998)"), ("srgb.jpg", "sRGB IEC61966-2.1"), ("plain.jpg", None)):
        out = oiio.ImageOutput.create(str(tmp_path / name))
        spec = oiio.ImageSpec(32, 24, 3, oiio.UINT8)
        if description is not None:
            profile = _icc_profile(description)
            spec.attribute("ICCProfile", oiio.TypeDesc(f"uint8[{len(profile)}]"), profile)
        assert out.open(str(tmp_path / name), spec) and out.write_image(pixels)
        out.close()
    photo._warned_profiles.clear()
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli.io.photo"):
        for name in ("adobe.jpg", "srgb.jpg", "plain.jpg", "adobe.jpg"):
            read_image(tmp_path / name)
    assert caplog.text.count("colour profile is 'Adobe RGB (1998)'") == 1 and "sRGB IEC" not in caplog.text
    linear = np.full((8, 8, 3), 0.2, np.float32)
    out = oiio.ImageOutput.create(str(tmp_path / "linear.png"))
    spec = oiio.ImageSpec(8, 8, 3, oiio.UINT16)
    spec.attribute("oiio:ColorSpace", "lin_rec709_scene")
    assert out.open(str(tmp_path / "linear.png"), spec) and out.write_image(linear)
    out.close()
    decoded = read_image(tmp_path / "linear.png")
    assert decoded.encoding == "linear" and np.allclose(decoded.pixels, 0.2, atol=1e-4)
    assert np.allclose(to_srgb(decoded), linear_to_srgb(np.float32(0.2)), atol=1e-3)


def _icc_profile(description: str) -> np.ndarray:
    """A minimal ICC v2 profile: its header and a 'desc' tag naming it (what OpenImageIO decodes)."""
    import struct

    text = description.encode("ascii") + b"\0"
    desc = b"desc" + bytes(4) + struct.pack(">I", len(text)) + text
    desc += bytes(-len(desc) % 4)
    size = 128 + 4 + 12 + len(desc)
    header = struct.pack(">I", size) + b"none" + bytes([2, 16, 0, 0]) + b"mntrRGB XYZ " + bytes(12) + b"acsp"
    header += bytes(128 - len(header))
    table = struct.pack(">I", 1) + b"desc" + struct.pack(">II", 144, len(desc))
    return np.frombuffer(header + table + desc, np.uint8)


@pytest.mark.parametrize("fmt, dtype", [("float", np.float32), ("half", np.float16), ("uint16", np.uint16)])
def test_grey_tiffs_opencv_misreads_keep_their_samples_and_orientation(tmp_path, caplog, fmt, dtype):
    """OpenCV refused a one-channel float TIFF as corrupt and read a 16-bit grey one with alpha at
    8 bits (40000 came back as 156 * 257). The oracle: the samples written, rotated as EXIF
    orientation 6 says (90 degrees clockwise), alpha warned of as for every photo."""
    rng = np.random.default_rng(5)
    grey = (rng.random((4, 6, 1)) * (1 if fmt != "uint16" else 65535)).astype(dtype)
    _write_oiio(tmp_path / "grey.tif", grey, fmt, Orientation=6)
    image = read_image(tmp_path / "grey.tif")
    scale = 65535 if fmt == "uint16" else 1
    expected = np.rot90(grey.astype(np.float32) / scale, k=-1)
    np.testing.assert_array_equal(image.pixels, np.repeat(expected, 3, axis=2))
    assert image.encoding == ("linear" if fmt != "uint16" else "srgb")
    with_alpha = np.concatenate([grey, np.full_like(grey, 1 if fmt != "uint16" else 65535)], axis=2)
    with_alpha[0, 0, 1] = 0
    _write_oiio(tmp_path / "ga.tif", with_alpha, fmt)
    with caplog.at_level(logging.WARNING):
        image = read_image(tmp_path / "ga.tif")
    np.testing.assert_array_equal(image.pixels, np.repeat(grey.astype(np.float32) / scale, 3, axis=2))
    assert "ga.tif: 4.2 % of its pixels are transparent" in caplog.text


def test_a_truncated_grey_tiff_is_refused_not_read_as_black(tmp_path, capfd):
    """OpenImageIO reads lazily: the error of a truncated strip came after the check, and the
    photo read as zeros (exit 0) under a hundred lines of libtiff's messages."""
    pixels = np.random.default_rng(2).random((150, 200, 1)).astype(np.float32)
    _write_oiio(tmp_path / "whole.tif", pixels, "float")
    data = (tmp_path / "whole.tif").read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[:len(data) // 2])
    with pytest.raises(InputError, match=r"cut.tif: cannot decode as TIF \(corrupt, truncated"):
        read_image(tmp_path / "cut.tif")
    assert capfd.readouterr().err == ""


def test_photos_beyond_opencvs_limits_are_refused_in_one_line(tmp_path, monkeypatch):
    """A side beyond 2**20 pixels was an internal error (cv2.error out of imdecode)."""
    assert cv2.imwrite(str(tmp_path / "wide.tif"), np.full((1, (1 << 20) + 10, 3), 100, np.uint8))
    with pytest.raises(InputError, match=r"wide.tif: OpenCV cannot decode it \(.*CV_IO_MAX_IMAGE_WIDTH.*\); downscale"):
        read_image(tmp_path / "wide.tif")
    import lumos3d_cli.io.photo as photo

    monkeypatch.setattr(photo, "OPENCV_MAX_PIXELS", 100)  # a 1-gigapixel photo, without holding one
    cv2.imwrite(str(tmp_path / "big.png"), np.zeros((10, 11, 3), np.uint8))
    with pytest.raises(InputError, match=r"big.png: 11x10 pixels is beyond what OpenCV decodes \(at most 1,048,576 a side"):
        read_image(tmp_path / "big.png")


def test_exr_channels_that_are_neither_rgb_nor_grey_are_refused(tmp_path):
    """Two colour channels (R, G) read as the first one repeated, G dropped without a word."""
    pixels = np.stack([np.full((3, 4), 0.2), np.full((3, 4), 0.8)], axis=2).astype(np.float32)
    _write_oiio(tmp_path / "rg.exr", pixels, "float")
    with pytest.raises(InputError, match=r"rg.exr: holds the channels R, G, neither RGB nor grey \(Y\)"):
        read_image(tmp_path / "rg.exr")
    height, width = pixels.shape[:2]
    spec = oiio.ImageSpec(width, height, 2, "float")
    spec.channelnames = ("A", "Y")
    out = oiio.ImageOutput.create(str(tmp_path / "ya.exr"))
    assert out.open(str(tmp_path / "ya.exr"), spec) and out.write_image(pixels)
    out.close()
    np.testing.assert_array_equal(read_image(tmp_path / "ya.exr").pixels, np.full((3, 4, 3), 0.8, np.float32))
