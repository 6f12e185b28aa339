import warnings

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.gaussians import Gaussians, sh_coefficient_count
from lumos3d_cli.io.ply import ply_property_names, read_ply, read_ply_fields, write_ply

from factories import random_gaussians


def _assert_same(a: Gaussians, b: Gaussians) -> None:
    for name, tensor in a.tensors().items():
        assert torch.equal(tensor, getattr(b, name)), name


@pytest.mark.parametrize("degree", [0, 1, 2, 3, 4])
def test_plyfile_reads_every_property_as_written(tmp_path, degree):
    gaussians = random_gaussians(50, degree, seed=degree)
    write_ply(tmp_path / "scene.ply", gaussians)
    ply = PlyData.read(str(tmp_path / "scene.ply"))
    assert ply.text is False and ply.byte_order == "<"
    vertex = ply["vertex"]
    names = [p.name for p in vertex.properties]
    assert names == ply_property_names(degree)
    assert all(vertex[name].dtype == np.float32 for name in names)
    g = gaussians.to(torch.float64)
    k = sh_coefficient_count(degree)
    np.testing.assert_array_equal(vertex["x"], gaussians.means[:, 0].numpy())
    np.testing.assert_array_equal(vertex["z"], gaussians.means[:, 2].numpy())
    np.testing.assert_array_equal(vertex["nx"], 0)
    for c in range(3):
        np.testing.assert_array_equal(vertex[f"f_dc_{c}"], gaussians.sh[:, 0, c].numpy())
        for j in range(1, k):  # channel-major: f_rest_{c*(K-1) + j-1} is coefficient j of channel c
            np.testing.assert_array_equal(vertex[f"f_rest_{c * (k - 1) + j - 1}"], gaussians.sh[:, j, c].numpy())
        np.testing.assert_allclose(vertex[f"scale_{c}"], torch.log(g.scales[:, c]).numpy(), rtol=1e-6)
    np.testing.assert_allclose(vertex["opacity"], torch.logit(g.opacities).numpy(), rtol=1e-5, atol=1e-6)
    for c in range(4):
        np.testing.assert_array_equal(vertex[f"rot_{c}"], gaussians.quats[:, c].numpy())


def test_round_trip_is_bit_exact(tmp_path):
    original = random_gaussians(2000, 3)
    write_ply(tmp_path / "a.ply", original)
    once = read_ply(tmp_path / "a.ply")
    # means, rotations and SH are stored as they are: exact after one trip.
    for name in ("means", "quats", "sh"):
        assert torch.equal(getattr(once, name), getattr(original, name))
    # Opacity and scale go through logit/log on disk: within float32 rounding after one trip ...
    torch.testing.assert_close(once.opacities, original.opacities, rtol=2e-6, atol=0)
    torch.testing.assert_close(once.scales, original.scales, rtol=2e-6, atol=0)
    # ... and bit-exact from then on: memory -> file -> memory leaves a saved scene unchanged.
    write_ply(tmp_path / "b.ply", once)
    _assert_same(read_ply(tmp_path / "b.ply"), once)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_extreme_values_stay_finite_on_disk(tmp_path):
    gaussians = random_gaussians(4, 1)
    gaussians.opacities = torch.tensor([0.0, 1.0, 1e-30, 0.5])
    gaussians.scales = torch.tensor([[0.0, 1e-30, 1e4]] * 4)
    write_ply(tmp_path / "a.ply", gaussians)
    fields, _ = read_ply_fields(tmp_path / "a.ply")
    assert np.isfinite(fields).all()
    back = read_ply(tmp_path / "a.ply")
    assert back.opacities[0] < 1e-6 and back.opacities[1] > 1 - 1e-6
    assert back.scales[0, 2] == pytest.approx(1e4, rel=1e-6)


def test_empty_scene(tmp_path):
    write_ply(tmp_path / "a.ply", random_gaussians(0, 2))
    back = read_ply(tmp_path / "a.ply")
    assert len(back) == 0 and back.sh_degree == 2


def test_non_finite_gaussians_are_refused(tmp_path):
    gaussians = random_gaussians(5, 0)
    gaussians.means[2, 1] = float("nan")
    with pytest.raises(NonFiniteError, match=r"scene to save\.means: 1 of 15"):
        write_ply(tmp_path / "a.ply", gaussians)
    assert not (tmp_path / "a.ply").exists()


@pytest.mark.parametrize("name", ["means", "quats", "scales", "sh"])
def test_float64_values_beyond_float32_are_refused_not_written_as_inf(tmp_path, name):
    """A float64 scene with a coordinate of 1e39 is finite, and was written as Inf (a scale as a
    log-scale of 89.8, which reading refuses); the .splat held Inf too."""
    from lumos3d_cli.io.splat import write_splat

    gaussians = random_gaussians(4, 1).to(torch.float64)
    getattr(gaussians, name).view(-1)[0] = 1e39
    for write, path in ((write_ply, tmp_path / "a.ply"), (write_splat, tmp_path / "a.splat")):
        with pytest.raises(ValueError, match=rf"\.{name}: 1 value\(s\) beyond float32's range \(1e\+39"):
            write(path, gaussians)
        assert not path.exists()


def test_a_log_scale_too_large_for_float32_is_named_as_such(tmp_path):
    """exp(1e4) is Inf: the file holds no NaN, so the refusal says what the value is."""
    records = np.zeros(2, dtype=[(name, "f4") for name in ply_property_names(0)])
    records["scale_1"] = [0.0, 1e4]
    PlyData([PlyElement.describe(records, "vertex")]).write(str(tmp_path / "huge.ply"))
    with pytest.raises(InputError, match=r"huge.ply: holds log-scales \(scale_\*\) up to 10000.*above 88.7"):
        read_ply(tmp_path / "huge.ply")
    records["scale_1"] = [0.0, 88.0]  # e^88, 1.7e38: finite, read as it is
    PlyData([PlyElement.describe(records, "vertex")]).write(str(tmp_path / "large.ply"))
    assert bool(torch.isfinite(read_ply(tmp_path / "large.ply").scales).all())


def test_values_that_activate_to_finite_ones_are_refused_and_counted_alike(tmp_path):
    """An Inf opacity (sigmoid 1) or a -Inf log-scale (exp 0) is finite once activated: read_ply
    checks the file's values, and `info` counts what read_ply refuses (NaN normals aside, which
    nothing reads)."""
    from lumos3d_cli.io.summaries import summarize_gaussian_file

    for name, value in (("opacity", np.inf), ("opacity", -np.inf), ("scale_2", -np.inf), ("scale_0", 200.0)):
        records = np.zeros(4, dtype=[(n, "f4") for n in ply_property_names(0)])
        records[name][1] = value
        records["nx"][2] = np.nan
        PlyData([PlyElement.describe(records, "vertex")]).write(str(tmp_path / "odd.ply"))
        expected = ("holds log-scales \\(scale_\\*\\) up to 200" if value == 200.0
                    else rf"1 value\(s\) no scene can use, NaN, Inf or log-scales above 88.7 \({name}: 1\)")
        with pytest.raises(InputError, match=rf"odd.ply: {expected}"):
            read_ply(tmp_path / "odd.ply")
        summary = summarize_gaussian_file(tmp_path / "odd.ply")
        assert summary["non_finite_values"] == 1 and summary["count"] == 4
        assert summary["scale"]["max"] == 1.0  # the other three Gaussians' exp(0)


def test_headers_that_claim_what_the_file_cannot_hold(tmp_path):
    header = "ply\nformat binary_little_endian 1.0\nelement vertex {count}\n{properties}end_header\n"
    properties = "".join(f"property float {name}\n" for name in ply_property_names(0))
    (tmp_path / "twice.ply").write_bytes(header.format(count=1, properties=properties + "property float x\n").encode())
    with pytest.raises(InputError, match=r"twice.ply: PLY header lists property 'x' of 'vertex' twice"):
        read_ply_fields(tmp_path / "twice.ply")
    # a count of 10^15 is refused from the file's size, before any memory is asked for
    (tmp_path / "count.ply").write_bytes(header.format(count=10**15, properties=properties).encode() + bytes(68))
    with pytest.raises(InputError, match=r"count.ply: PLY data is truncated \(68 of 68000000000000000 bytes"):
        read_ply_fields(tmp_path / "count.ply")


def _plyfile_scene(names, n=3, text=False, byte_order="<", dtype="f4"):
    records = np.zeros(n, dtype=[(name, dtype) for name in names])
    for i, name in enumerate(names):
        records[name] = np.arange(n) + i * 0.25
    return PlyData([PlyElement.describe(records, "vertex")], text=text, byte_order=byte_order)


def test_reads_files_from_other_writers(tmp_path):
    names = ply_property_names(1)
    shuffled = names[::-1] + ["extra_property"]
    _plyfile_scene(shuffled).write(str(tmp_path / "reordered.ply"))
    _plyfile_scene(names, text=True).write(str(tmp_path / "ascii.ply"))
    _plyfile_scene(names, byte_order=">", dtype="f8").write(str(tmp_path / "big.ply"))
    expected = np.stack([np.arange(3) + names.index(n) * 0.25 for n in names], axis=1)
    expected_shuffled = np.stack([np.arange(3) + shuffled.index(n) * 0.25 for n in names], axis=1)
    fields, degree = read_ply_fields(tmp_path / "reordered.ply")
    assert degree == 1
    np.testing.assert_array_equal(fields, expected_shuffled.astype(np.float32))
    for name in ("ascii.ply", "big.ply"):
        fields, degree = read_ply_fields(tmp_path / name)
        np.testing.assert_array_equal(fields, expected.astype(np.float32))


@pytest.mark.parametrize(("text", "byte_order"), [(False, "<"), (False, ">"), (True, "<")])
def test_a_float64_file_beyond_float32_is_refused_naming_the_property(tmp_path, text, byte_order):
    """numpy's overflow warning, then the finite 1e39 called "NaN or Inf" (info: exit 0)."""
    scene = _plyfile_scene(ply_property_names(0), dtype="f8", text=text, byte_order=byte_order)
    scene["vertex"].data["y"][1] = -1e39
    scene.write(str(tmp_path / "far.ply"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=r"far\.ply: property y holds values up to 1e\+39, beyond the float32 range"):
            read_ply_fields(tmp_path / "far.ply")


def test_missing_normals_are_allowed(tmp_path):
    names = [n for n in ply_property_names(0) if n not in ("nx", "ny", "nz")]
    _plyfile_scene(names).write(str(tmp_path / "a.ply"))
    assert len(read_ply(tmp_path / "a.ply")) == 3


def test_missing_properties_are_listed(tmp_path):
    names = [n for n in ply_property_names(0) if n not in ("opacity", "rot_2")]
    _plyfile_scene(names).write(str(tmp_path / "a.ply"))
    with pytest.raises(InputError, match=r"a\.ply: not a 3D Gaussian scene; missing vertex properties: opacity, rot_2"):
        read_ply(tmp_path / "a.ply")


def test_bad_files(tmp_path):
    (tmp_path / "text.ply").write_text("hello")
    with pytest.raises(InputError, match="not a PLY file"):
        read_ply(tmp_path / "text.ply")
    write_ply(tmp_path / "cut.ply", random_gaussians(10, 0))
    data = (tmp_path / "cut.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-20])
    with pytest.raises(InputError, match="PLY data is truncated"):
        read_ply(tmp_path / "cut.ply")
    _plyfile_scene(ply_property_names(0) + ["f_rest_0"]).write(str(tmp_path / "odd.ply"))
    with pytest.raises(InputError, match="1 f_rest_\\* properties do not match any SH degree"):
        read_ply(tmp_path / "odd.ply")
    with pytest.raises(InputError, match="no such file"):
        read_ply(tmp_path / "missing.ply")
    with pytest.raises(InputError, match="is a folder; give the scene's .ply file"):
        read_ply(tmp_path)


def test_the_library_writers_replace_a_file_only_when_asked(tmp_path):
    """`write_ply`, `write_splat` and `save_checkpoint` replaced any file (a user's, or a link's
    target with the link turned into a file) without a word."""
    from lumos3d_cli.io.splat import write_splat
    from lumos3d_cli.model.checkpoints import save_checkpoint
    from lumos3d_cli.model.lumos3d import build_model

    gaussians = random_gaussians(8, 1, seed=0)
    writers = {"scene.ply": lambda path, **kw: write_ply(path, gaussians, **kw),
               "scene.splat": lambda path, **kw: write_splat(path, gaussians, **kw),
               "weights.safetensors": lambda path, **kw: save_checkpoint(build_model("tiny", seed=0), path, **kw)}
    (tmp_path / "target.txt").write_text("the user's")
    for name, write in writers.items():
        (tmp_path / name).write_text("mine")
        with pytest.raises(InputError, match=f"{name}: exists; lumos3d does not replace it unless asked"):
            write(tmp_path / name)
        assert (tmp_path / name).read_text() == "mine"
        link = tmp_path / f"link-{name}"
        link.symlink_to(tmp_path / "target.txt")
        with pytest.raises(InputError, match="exists"):
            write(link)
        assert link.is_symlink() and (tmp_path / "target.txt").read_text() == "the user's"
        (tmp_path / f"folder-{name}").mkdir()
        with pytest.raises(InputError, match="is a folder; give a file name"):
            write(tmp_path / f"folder-{name}", overwrite=True)
        write(tmp_path / name, overwrite=True)
        assert (tmp_path / name).read_bytes() != b"mine"
