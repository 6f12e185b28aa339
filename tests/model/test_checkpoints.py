import dataclasses
import json
import logging
import pathlib
import pickle
import re
import warnings

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.model.architectures import ARCHITECTURES, Architecture, PatchEmbedConfig, get_architecture
from lumos3d_cli.model.bundled_models import BUNDLED_MODELS, bundled_weights_path
from lumos3d_cli.model.checkpoints import read_checkpoint, save_checkpoint, summarize_checkpoint
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.typed_config import from_dict, to_dict

# VGGT's key structure (DINOv2 patch embed with registers, QK-norm blocks, camera and DPT heads)
# at a size that builds and runs in a fraction of a second.
REDUCED = dataclasses.replace(
    ARCHITECTURES["tiny"], name="reduced-vggt", image_size=56, sh_degree=2, gaussian_head_hidden=24,
    patch_embed=PatchEmbedConfig(kind="dinov2", depth=2, num_heads=4),
)
IMAGES = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(0))


@pytest.fixture(scope="module")
def source():
    return build_model(REDUCED, seed=0).eval()


@pytest.fixture(scope="module")
def expected(source):
    with torch.no_grad():
        return source(IMAGES)


def _vggt_state(model) -> dict[str, torch.Tensor]:
    """The model's weights as VGGT lays them out: no Gaussian head, plus point and track heads."""
    state = {k: v.clone() for k, v in model.state_dict().items() if not k.startswith("gaussian_head.")}
    state["point_head.scratch.output_conv2.2.weight"] = torch.randn(4, 32, 1, 1)
    state["track_head.tracker.query_ref_token"] = torch.randn(1, 2, 388)
    return state


def _anysplat_state(model) -> dict[str, torch.Tensor]:
    state = {}
    for key, value in model.state_dict().items():
        key = key.replace("gaussian_head.", "gaussian_param_head.", 1)
        state[f"encoder.{key}"] = value.clone()
    return state


def _outputs(model):
    with torch.no_grad():
        return model(IMAGES)


def test_our_format_round_trip(tmp_path, source, expected):
    path = save_checkpoint(source, tmp_path / "run" / "tiny.safetensors", {"steps": 10, "data": "test"})
    loaded = load_model(path)
    assert loaded.architecture == REDUCED and not loaded.training
    assert loaded.provenance["steps"] == 10 and loaded.provenance["format"] == "lumos3d"
    # loaded weights stay trainable (fine-tuning), except DINOv2's unused mask token
    assert {n for n, p in loaded.named_parameters() if not p.requires_grad} == {"aggregator.patch_embed.mask_token"}
    actual = _outputs(loaded)
    assert torch.equal(actual.pose_enc, expected.pose_enc) and torch.equal(actual.depth, expected.depth)
    assert torch.equal(actual.gaussians[0].sh, expected.gaussians[0].sh)
    summary = summarize_checkpoint(path)
    assert summary["format"] == "lumos3d" and summary["architecture"] == "reduced-vggt"
    assert summary["parameters"] == sum(p.numel() for p in source.parameters())
    assert summary["provenance"] == {"steps": 10, "data": "test"} and summary["fresh_modules"] == []
    with pytest.raises(InputError, match="carries its own architecture"):
        load_model(path, architecture=REDUCED)


def _config(path) -> dict:
    with safe_open(str(path), framework="pt") as handle:
        return json.loads(handle.metadata()["lumos3d"])


@pytest.mark.parametrize("mode", sorted(BUNDLED_MODELS))
def test_format_version_1_names_the_architecture_preset_and_the_bundled_files_load(tmp_path, source, mode):
    """The JSON key "preset" is a format fact (files written before the rename, the bundled weights
    among them): read from the real bundled files, and still written, so every file stays readable."""
    bundled = bundled_weights_path(BUNDLED_MODELS[mode])
    config = _config(bundled)
    assert config["format_version"] == 1 and "architecture" not in config
    architecture = read_checkpoint(bundled).architecture
    # both modes ship the appearance operator (model-card.md)
    assert architecture == from_dict(Architecture, config["preset"]) == ARCHITECTURES["tiny-operator"]
    written = save_checkpoint(source, tmp_path / "new.safetensors")
    assert from_dict(Architecture, _config(written)["preset"]) == REDUCED


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_official_vggt_layout_loads_with_a_fresh_gaussian_head(tmp_path, caplog, source, expected, suffix):
    path = tmp_path / f"model{suffix}"
    state = _vggt_state(source)
    if suffix == ".pt":
        torch.save(state, path)
    else:
        save_file(state, str(path))
    with caplog.at_level(logging.INFO, logger="lumos3d_cli"):
        loaded = load_model(tmp_path, architecture=REDUCED)  # a folder holding model.* works too
    assert "ignored 2 tensors" in caplog.text and "point_head, track_head" in caplog.text
    assert any(r.levelno == logging.WARNING and "gaussian_head" in r.getMessage() for r in caplog.records)
    assert loaded.provenance["format"] == "vggt"
    actual = _outputs(loaded)
    assert torch.equal(actual.pose_enc, expected.pose_enc)
    assert torch.equal(actual.depth, expected.depth) and torch.equal(actual.depth_conf, expected.depth_conf)
    summary = summarize_checkpoint(path, REDUCED)
    assert summary["format"] == "vggt" and summary["ignored_tensors"] == 2 and summary["fresh_modules"] == ["gaussian_head"]


def test_anysplat_layout_loads_everything_and_reads_the_sh_degree(tmp_path, source, expected):
    path = tmp_path / "model.safetensors"
    save_file(_anysplat_state(source), str(path))
    loaded = load_model(path, architecture=dataclasses.replace(REDUCED, sh_degree=4, gaussian_head_hidden=128))
    assert loaded.architecture.sh_degree == 2 and loaded.architecture.gaussian_head_hidden == 24
    actual = _outputs(loaded)
    assert torch.equal(actual.pose_enc, expected.pose_enc) and torch.equal(actual.depth, expected.depth)
    for name, tensor in expected.gaussians[0].tensors().items():
        assert torch.equal(getattr(actual.gaussians[0], name), tensor), name
    assert summarize_checkpoint(path, REDUCED)["format"] == "anysplat"


def test_half_precision_files_load_as_float32(tmp_path, source):
    path = tmp_path / "model.safetensors"
    save_file({k: v.to(torch.bfloat16) for k, v in _anysplat_state(source).items()}, str(path))
    loaded = load_model(path, architecture=REDUCED)
    assert all(p.dtype == torch.float32 for p in loaded.parameters())
    assert summarize_checkpoint(path, REDUCED)["dtypes"] == {"bfloat16": len(source.state_dict())}


def test_weights_holding_nan_are_not_written(tmp_path):
    model = build_model("tiny", seed=0)
    with torch.no_grad():
        next(model.parameters())[0].fill_(float("nan"))
    name = next(name for name, _ in model.named_parameters())
    with pytest.raises(NonFiniteError, match=f"^{name}: .* NaN or Inf; the weights are damaged"):
        save_checkpoint(model, tmp_path / "model.safetensors")
    assert list(tmp_path.iterdir()) == []


def test_mismatches_list_missing_unexpected_and_misshaped_keys(tmp_path, source):
    state = _vggt_state(source)
    del state["aggregator.camera_token"]
    state["aggregator.extra"] = torch.zeros(1)
    state["depth_head.norm.weight"] = torch.zeros(7)
    torch.save(state, tmp_path / "model.pt")
    with pytest.raises(InputError) as error:
        load_model(tmp_path / "model.pt", architecture=REDUCED)
    message = str(error.value)
    assert "1 missing keys: aggregator.camera_token" in message
    assert "1 unexpected keys: aggregator.extra" in message
    assert "depth_head.norm.weight (file (7,), model (256,))" in message


def test_long_key_lists_are_truncated(tmp_path, source):
    state = _vggt_state(source)
    state.update({f"aggregator.bogus_{i:02d}": torch.zeros(1) for i in range(25)})
    torch.save(state, tmp_path / "model.pt")
    with pytest.raises(InputError, match=r"25 unexpected keys: .*bogus_03 \.\.\. and 21 more"):
        load_model(tmp_path / "model.pt", architecture=REDUCED)


def test_the_wrong_architecture_for_an_official_file_is_a_shape_error(tmp_path, source):
    torch.save(_vggt_state(source), tmp_path / "model.pt")
    with pytest.raises(InputError, match="does not fit the model") as error:
        load_model(tmp_path / "model.pt", architecture=get_architecture("vggt-1b"))
    assert "It was read as the 'vggt-1b' architecture; pass the one it was trained at (tiny, small" in str(error.value)
    assert len(str(error.value)) < 1000  # one readable line, not a dump of key names
    with pytest.raises(InputError, match="does not fit the model") as error:
        load_model(tmp_path / "model.pt")  # no architecture fits this reduced size
    assert "fits none of lumos3d's architectures (tiny, small" in str(error.value) and len(str(error.value)) < 1000
    with pytest.raises(InputError, match="fits none of lumos3d's architectures"):
        summarize_checkpoint(tmp_path / "model.pt")  # `info` checks the file as loading does


def test_a_foreign_file_of_a_smaller_architecture_is_read_at_the_size_it_fits(tmp_path):
    """A VGGT-layout file at the `tiny` size loads without naming it; `info` reports that size, the
    Gaussian head freshly made, and the same file gives the same fresh head every time."""
    model = build_model("tiny", seed=3)
    state = {key: tensor for key, tensor in model.state_dict().items() if not key.startswith("gaussian_head.")}
    save_file(state, str(tmp_path / "model.safetensors"))
    first, second = load_model(tmp_path / "model.safetensors"), load_model(tmp_path / "model.safetensors")
    assert first.architecture.name == "tiny" and first.provenance["format"] == "vggt"
    assert torch.equal(first.aggregator.camera_token, model.aggregator.camera_token)
    assert all(torch.equal(a, b) for a, b in zip(first.gaussian_head.parameters(), second.gaussian_head.parameters()))
    summary = summarize_checkpoint(tmp_path / "model.safetensors")
    assert summary["architecture"] == "tiny" and summary["fresh_modules"] == ["gaussian_head"]
    assert summary["parameters"] == sum(t.numel() for t in state.values())


class _Payload:
    """Unpickling this would create a file: proof that loading executes no pickled code."""

    def __init__(self, target: pathlib.Path):
        self.target = target

    def __reduce__(self):
        return (pathlib.Path.touch, (self.target,))


def test_pickled_code_is_never_executed(tmp_path):
    target = tmp_path / "executed"
    torch.save({"aggregator.camera_token": torch.zeros(1), "payload": _Payload(target)}, tmp_path / "model.pt")
    with pytest.raises(InputError, match="holds objects other than tensors, which lumos3d does not unpickle"):
        read_checkpoint(tmp_path / "model.pt")
    assert not target.exists()


def test_files_that_are_no_checkpoint_are_refused(tmp_path):
    save_file({"weight": torch.zeros(2)}, str(tmp_path / "other.safetensors"))
    with pytest.raises(InputError, match="not a Lumos3D, VGGT or AnySplat checkpoint"):
        read_checkpoint(tmp_path / "other.safetensors")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputError, match="not a checkpoint"):
        read_checkpoint(tmp_path / "notes.txt")
    (tmp_path / "broken.safetensors").write_bytes(b"\x00" * 5)
    with pytest.raises(InputError, match="cannot read as safetensors"):
        read_checkpoint(tmp_path / "broken.safetensors")
    torch.save([torch.zeros(1)], tmp_path / "list.pt")
    with pytest.raises(InputError, match="not a state dict"):
        read_checkpoint(tmp_path / "list.pt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="folder holds none of"):
        read_checkpoint(tmp_path / "empty")


def test_tensors_no_network_parameter_can_take_are_refused_naming_them(tmp_path, source):
    """Integer keys, bool/int/complex and sparse tensors loaded until torch failed deep inside (an
    internal error) or, for complex, silently lost their imaginary part."""
    state = _vggt_state(source)
    first = "aggregator.camera_token"
    torch.save({0: state[first], **state}, tmp_path / "int_key.pt")
    with pytest.raises(InputError, match=r"int_key\.pt: is not a state dict: keys must be names \(text\), not 0"):
        read_checkpoint(tmp_path / "int_key.pt", REDUCED)
    for dtype in (torch.bool, torch.int32, torch.complex64):
        path = tmp_path / f"{str(dtype).removeprefix('torch.')}.pt"
        torch.save({**state, first: state[first].to(dtype)}, path)
        for read in (read_checkpoint, summarize_checkpoint):
            with pytest.raises(InputError, match=rf"tensor {first} holds {path.stem} values; the network's weights are floating"):
                read(path, REDUCED)
    weight = "aggregator.frame_blocks.0.attn.qkv.weight"
    torch.save({**state, weight: state[weight].to_sparse()}, tmp_path / "sparse.pt")
    with pytest.raises(InputError, match=rf"holds sparse tensors \({weight}\); save the weights as dense"):
        read_checkpoint(tmp_path / "sparse.pt", REDUCED)


def test_a_zip_bomb_is_refused_before_torch_expands_it(tmp_path, source):
    """A 1 MB .pt whose one entry deflates to 1 GB took 1.4 GB of memory in `info` before it was
    found to be no checkpoint: torch.save stores its entries uncompressed."""
    import zipfile

    path = tmp_path / "bomb.pt"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        with archive.open("bomb/data/0", "w", force_zip64=True) as entry:
            for _ in range(80):
                entry.write(bytes(1 << 20))  # 80 MiB of zeros, streamed: a few kB on disk
    for read in (read_checkpoint, summarize_checkpoint):
        with pytest.raises(InputError, match=r"bomb\.pt: entry bomb/data/0 expands \d+-fold to 0.08 GiB; torch.save "
                                             r"compresses nothing"):
            read(path)
    torch.save(_vggt_state(source), tmp_path / "vggt.pt")  # what torch.save writes is read as before
    assert read_checkpoint(tmp_path / "vggt.pt", REDUCED).format == "vggt"


def test_two_keys_naming_one_parameter_are_refused(tmp_path, source):
    """AnySplat's `encoder.x` beside an unprefixed `x`: one copy won by key order, the load called strict."""
    state = _anysplat_state(source)
    state["aggregator.camera_token"] = torch.zeros_like(state["encoder.aggregator.camera_token"])
    save_file(state, str(tmp_path / "twice.safetensors"))
    for read in (read_checkpoint, summarize_checkpoint):
        with pytest.raises(InputError, match=r"keys name one parameter twice: aggregator.camera_token and "
                                             r"encoder.aggregator.camera_token \(both aggregator.camera_token\)"):
            read(tmp_path / "twice.safetensors", REDUCED)


@pytest.mark.parametrize(("field", "value", "message"), [
    ("camera_iterations", 0, "camera_iterations must be at least 1"),  # an IndexError in the camera head
    ("opacity_threshold", 1.5, "0 <= opacity_threshold < 1"),  # a scene of no Gaussians, exit 0
    ("image_size", 22400, "image_size must be at most 2048"),
    ("gaussian_scale_base", -0.001, "gaussian_scale_base, mlp_ratio and rope_frequency must be positive"),
    ("rope_frequency", 0.0, "gaussian_scale_base, mlp_ratio and rope_frequency must be positive"),
    ("gaussian_scale_max", float("inf"), "every number must be finite"),
])
def test_settings_in_a_checkpoints_header_are_range_checked(tmp_path, source, field, value, message):
    path = save_checkpoint(source, tmp_path / "ours.safetensors")
    with safe_open(str(path), framework="pt") as handle:
        config = json.loads(handle.metadata()["lumos3d"])
        tensors = {key: handle.get_tensor(key) for key in handle.keys()}
    config["preset"][field] = value
    save_file(tensors, str(path), metadata={"lumos3d": json.dumps(config)})
    for read in (read_checkpoint, summarize_checkpoint):
        with pytest.raises(InputError, match=rf"config is damaged .*{re.escape(message)}"):
            read(path)


def test_damaged_config_and_unknown_sh_layouts_are_refused(tmp_path, source):
    path = tmp_path / "ours.safetensors"
    save_file({k: v.contiguous() for k, v in source.state_dict().items()}, str(path), metadata={"lumos3d": "{not json"})
    with pytest.raises(InputError, match="config is damaged"):
        read_checkpoint(path)
    save_file({k: v.contiguous() for k, v in source.state_dict().items()}, str(path), metadata={"lumos3d": json.dumps({"format_version": 99})})
    with pytest.raises(InputError, match="format version 99"):
        read_checkpoint(path)
    save_file({k: v.contiguous() for k, v in source.state_dict().items()}, str(path),
              metadata={"lumos3d": json.dumps({"format_version": 1, "preset": {"name": "x", "depth": "deep"}})})
    with pytest.raises(InputError, match="config is damaged .*'preset.depth': expected an integer"):
        read_checkpoint(path)
    state = _anysplat_state(source)
    state["encoder.gaussian_param_head.scratch.output_conv2.2.weight"] = torch.zeros(50, 24, 1, 1)
    save_file(state, str(tmp_path / "model.safetensors"))
    with pytest.raises(InputError, match="50 output channels"):
        read_checkpoint(tmp_path / "model.safetensors")
    state["encoder.gaussian_param_head.scratch.output_conv2.2.weight"] = torch.zeros(84)
    save_file(state, str(tmp_path / "model.safetensors"))
    with pytest.raises(InputError, match=r"has shape \(84,\); a convolution's weight has 4 dimensions"):
        read_checkpoint(tmp_path / "model.safetensors")


@pytest.mark.parametrize(("change", "message"), [
    ({"num_heads": 0}, "num_heads must be positive"),  # was a ZeroDivisionError
    ({"patch_size": 0}, "patch_size must be positive"),
    ({"camera_num_heads": -2}, "camera_num_heads must be positive"),
    ([], "'preset': expected a mapping, got \\[\\]"),  # the whole architecture
    ("provenance", "provenance: expected a mapping, got 'by hand'"),
    ("version", "format version '1' is not supported"),  # a string, not the number 1
])
def test_damaged_fields_of_our_config_are_named(tmp_path, source, change, message):
    config = {"format_version": 1, "preset": to_dict(source.architecture), "provenance": {}}
    if change == "provenance":
        config["provenance"] = "by hand"
    elif change == "version":
        config["format_version"] = "1"
    elif isinstance(change, dict):
        config["preset"].update(change)
    else:
        config["preset"] = change
    path = tmp_path / "ours.safetensors"
    save_file({k: v.contiguous() for k, v in source.state_dict().items()}, str(path), metadata={"lumos3d": json.dumps(config)})
    for read in (read_checkpoint, summarize_checkpoint):
        with pytest.raises(InputError, match=f"^{path}: .*{message}"):
            read(path)


def test_bare_state_dicts_and_anysplat_encoder_dicts(tmp_path, source, expected):
    """Our module names without our metadata name the problem (no architecture to read them at);
    AnySplat's encoder saved on its own (no `encoder.` prefix) loads as AnySplat's whole model does."""
    torch.save(source.state_dict(), tmp_path / "bare.pt")
    with pytest.raises(InputError, match="lumos3d's own module names but no lumos3d metadata"):
        read_checkpoint(tmp_path / "bare.pt", architecture=REDUCED)
    encoder = {key.removeprefix("encoder."): tensor for key, tensor in _anysplat_state(source).items()}
    torch.save(encoder, tmp_path / "encoder.pt")
    loaded = load_model(tmp_path / "encoder.pt", architecture=REDUCED)
    assert loaded.provenance["format"] == "anysplat" and loaded.architecture.sh_degree == 2
    assert torch.equal(_outputs(loaded).depth, expected.depth)


def test_float64_weights_beyond_float32_and_upper_case_suffixes(tmp_path, source):
    state = {key: tensor.double() for key, tensor in _vggt_state(source).items()}
    save_file(state, str(tmp_path / "model.SAFETENSORS"))  # a suffix in capitals is still a checkpoint
    assert read_checkpoint(tmp_path / "model.SAFETENSORS", REDUCED).tensors["aggregator.camera_token"].dtype == torch.float32
    state["aggregator.camera_token"] = torch.full_like(state["aggregator.camera_token"], 1e300)
    save_file(state, str(tmp_path / "huge.safetensors"))
    with pytest.raises(InputError, match=r"tensor aggregator.camera_token holds values up to 1e\+300, beyond the float32 range"):
        read_checkpoint(tmp_path / "huge.safetensors", REDUCED)


def test_a_raw_pickle_is_refused_without_torch_warnings(tmp_path):
    (tmp_path / "raw.pt").write_bytes(pickle.dumps({"aggregator.camera_token": [1.0]}, protocol=4))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InputError, match="raw.pt: "):
            read_checkpoint(tmp_path / "raw.pt")
    assert [str(w.message) for w in caught] == []  # torch's "Detected pickle protocol 4" would print two lines


@pytest.mark.slow
def test_full_size_vggt_1b_official_layout_round_trip(tmp_path):
    """The real VGGT-1B size: random weights saved as model.pt with the official names and
    shapes, loaded back strictly (about 5 GB on disk and 10 GB of memory)."""
    source = build_model("vggt-1b", seed=0).eval()
    state = {k: v for k, v in source.state_dict().items() if not k.startswith("gaussian_head.")}
    torch.save(state, tmp_path / "model.pt")
    loaded = load_model(tmp_path / "model.pt")
    assert loaded.architecture.name == "vggt-1b"
    for key, value in state.items():
        assert torch.equal(loaded.state_dict()[key], value), key
    images = torch.rand(1, 1, 3, 28, 28)
    with torch.no_grad():
        assert torch.equal(loaded(images).depth, source(images).depth)


def test_saved_checkpoints_follow_the_umask(tmp_path):
    """safetensors replaces the temporary file with its own 0600 one; ours must still follow the umask."""
    import os

    previous = os.umask(0o022)
    try:
        path = save_checkpoint(build_model("tiny", seed=0), tmp_path / "m.safetensors")
    finally:
        os.umask(previous)
    assert path.stat().st_mode & 0o777 == 0o644
