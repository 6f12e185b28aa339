"""Model checkpoints: our format, and the official VGGT-1B and AnySplat layouts mapped onto
`model.lumos3d.Lumos3D` (the file handling itself is `io/weight_files.py`).

Our format is one `.safetensors` file whose header metadata holds a JSON config under the key
"lumos3d": {"format_version", "preset": {...every Architecture field...}, "provenance": {...}}.
The key "preset" is a fact of format version 1 (written before the model size was called an
architecture); it holds the architecture and keeps its name so that every file written so far,
the bundled weights included, loads unchanged. The tensors use the module names of
`model.lumos3d.Lumos3D`.

Foreign layouts are recognised by their key names:
  VGGT     (`model.pt` state dict or `model.safetensors`): aggregator.*, camera_head.*,
           depth_head.*; point_head.* and track_head.* are ignored; there is no Gaussian head.
  AnySplat (`model.safetensors`): encoder.aggregator.*, encoder.camera_head.*,
           encoder.depth_head.*, encoder.gaussian_param_head.* (-> gaussian_head.*).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import require_new_file
from lumos3d_cli.io.state_dicts import check_shapes, listing
from lumos3d_cli.io.weight_files import read_header, read_weights, resolve_weights_file, write_weights
from lumos3d_cli.model.architectures import ARCHITECTURES, Architecture, get_architecture
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.typed_config import from_dict, to_dict

logger = logging.getLogger(__name__)

FORMAT_LUMOS3D = "lumos3d"
FORMAT_VGGT = "vggt"
FORMAT_ANYSPLAT = "anysplat"
METADATA_KEY = "lumos3d"
FORMAT_VERSION = 1
ARCHITECTURE_KEY = "preset"  # format version 1's name for the architecture in the JSON config
OFFICIAL_ARCHITECTURE = "vggt-1b"
_GAUSSIAN_OUTPUT = "gaussian_head.scratch.output_conv2.2.weight"


@dataclass
class Checkpoint:
    """A checkpoint read into memory, renamed to our module names.

    tensors: float32 tensors keyed by our parameter names; ignored: file keys dropped on purpose
    (VGGT's point and track heads); fresh_modules: our top-level modules the file does not
    provide (VGGT has no Gaussian head), to be initialised randomly.
    """

    path: Path
    format: str
    architecture: Architecture
    tensors: dict[str, torch.Tensor]
    provenance: dict = field(default_factory=dict)
    ignored: list[str] = field(default_factory=list)
    fresh_modules: list[str] = field(default_factory=list)


def save_checkpoint(model: Lumos3D, path: Path | str, provenance: dict | None = None, dtype: str = "float32",
                    overwrite: bool = False) -> Path:
    """Write `model` in our format (atomically), to a new file unless `overwrite` (an existing one
    is an InputError). `provenance` (JSON-serialisable) records how the weights were made, e.g.
    training data, steps, git commit. `dtype` is the storage precision of floating-point tensors
    ("float16" halves the file; loading always returns float32)."""
    require_new_file(Path(path), overwrite)
    config = {"format_version": FORMAT_VERSION, ARCHITECTURE_KEY: to_dict(model.architecture), "provenance": provenance or {}}
    return write_weights(model.state_dict(), Path(path), {METADATA_KEY: json.dumps(config)}, dtype)


def _detect_format(path: Path, keys: list[str], metadata: dict[str, str]) -> str:
    if METADATA_KEY in metadata:
        return FORMAT_LUMOS3D
    # AnySplat's whole model (encoder.*) or its encoder's own state dict (gaussian_param_head.* beside aggregator.*)
    if any(k.startswith(("encoder.aggregator.", "gaussian_param_head.")) for k in keys):
        return FORMAT_ANYSPLAT
    if any(k.startswith(("gaussian_head.", "illumination_head.")) for k in keys):
        raise InputError(
            f"{path}: holds lumos3d's own module names but no lumos3d metadata, so its architecture is unknown "
            "(a bare state_dict); use the .safetensors file lumos3d wrote (save_checkpoint, lumos3d train)"
        )
    if any(k.startswith("aggregator.") for k in keys) and any(k.startswith(("camera_head.", "depth_head.")) for k in keys):
        return FORMAT_VGGT
    raise InputError(
        f"{path}: not a Lumos3D, VGGT or AnySplat checkpoint (no lumos3d metadata, no aggregator.* keys; "
        f"first keys: {listing(sorted(keys))})"
    )


def _our_name(file_format: str, key: str) -> str | None:
    """Our parameter name for a file key; None for keys dropped on purpose."""
    if file_format == FORMAT_VGGT and key.startswith(("point_head.", "track_head.")):
        return None
    if file_format == FORMAT_ANYSPLAT:
        if key.startswith("encoder.distill_"):
            return None  # AnySplat's frozen teacher copy, if a training checkpoint holds it
        key = key.removeprefix("encoder.")
        if key.startswith("gaussian_param_head."):
            return "gaussian_head." + key.removeprefix("gaussian_param_head.")
        return key
    return key


def _our_config(path: Path, metadata: dict[str, str]) -> tuple[Architecture, dict]:
    try:
        config = json.loads(metadata[METADATA_KEY])
        version = config.get("format_version")
    except (json.JSONDecodeError, AttributeError) as error:
        raise InputError(f"{path}: the checkpoint's lumos3d config is damaged ({error})") from None
    if version != FORMAT_VERSION:
        raise InputError(f"{path}: checkpoint format version {version!r} is not supported (expected {FORMAT_VERSION})")
    provenance = config.get("provenance", {})
    try:
        if not isinstance(provenance, dict):
            raise InputError(f"provenance: expected a mapping, got {provenance!r}")
        return from_dict(Architecture, config[ARCHITECTURE_KEY], ARCHITECTURE_KEY), provenance
    except (KeyError, InputError) as error:
        raise InputError(f"{path}: the checkpoint's lumos3d config is damaged ({error})") from None


def _anysplat_architecture(path: Path, base: Architecture, shapes: dict[str, tuple[int, ...]]) -> Architecture:
    """`base` with the SH degree and head width read off the Gaussian head's output conv."""
    if _GAUSSIAN_OUTPUT not in shapes:
        raise InputError(f"{path}: AnySplat checkpoint without encoder.gaussian_param_head.scratch.output_conv2.2.weight")
    if len(shapes[_GAUSSIAN_OUTPUT]) != 4:
        raise InputError(f"{path}: encoder.gaussian_param_head.scratch.output_conv2.2.weight has shape "
                         f"{shapes[_GAUSSIAN_OUTPUT]}; a convolution's weight has 4 dimensions")
    channels, hidden = shapes[_GAUSSIAN_OUTPUT][:2]
    coefficients = (channels - 9) / 3
    degree = round(coefficients**0.5) - 1 if coefficients > 0 else -1
    if degree < 0 or degree > 4 or (degree + 1) ** 2 != coefficients:
        raise InputError(f"{path}: Gaussian head has {channels} output channels, which fits no SH degree 0..4")
    return dataclasses.replace(base, sh_degree=degree, gaussian_head_hidden=hidden)


@dataclass
class _Layout:
    """How a file's keys map onto our network (everything but the tensor data)."""

    format: str
    architecture: Architecture
    provenance: dict
    names: dict[str, str]  # file key -> our parameter name
    ignored: list[str]
    fresh_modules: list[str]


def _interpret(path: Path, shapes: dict[str, tuple[int, ...]], metadata: dict[str, str], architecture: Architecture | None) -> _Layout:
    """How the file's keys (`shapes`, by file key) map onto our network, checked key by key and
    shape by shape against it (InputError otherwise). A foreign file (VGGT, AnySplat) names no size:
    `architecture` gives it, else the first of ARCHITECTURES it fits (vggt-1b, the official size,
    tried first)."""
    file_format = _detect_format(path, list(shapes), metadata)
    names = {key: _our_name(file_format, key) for key in shapes}
    ignored = sorted(key for key, name in names.items() if name is None)
    names = {key: name for key, name in names.items() if name is not None}
    # AnySplat's `encoder.x` and an unprefixed `x` beside it name one parameter: one copy would
    # win by key order, silently
    twice = sorted(f"{' and '.join(sorted(k for k, n in names.items() if n == name))} (both {name})"
                   for name, count in Counter(names.values()).items() if count > 1)
    if twice:
        raise InputError(f"{path}: keys name one parameter twice: {listing(twice)}; keep one of each")
    used = {name: shapes[key] for key, name in names.items()}
    if file_format == FORMAT_LUMOS3D:
        if architecture is not None:
            raise InputError(f"{path}: is a Lumos3D checkpoint and carries its own architecture; do not pass one")
        architecture, provenance = _our_config(path, metadata)
        _require_fits(path, architecture, [], used)
        return _Layout(file_format, architecture, provenance, names, ignored, [])
    provenance = {"source": f"{'VGGT' if file_format == FORMAT_VGGT else 'AnySplat'} checkpoint", "file": path.name}
    fresh_modules = ["gaussian_head"] if file_format == FORMAT_VGGT else []
    official = get_architecture(OFFICIAL_ARCHITECTURE)
    candidates = [architecture] if architecture else [official, *(a for a in ARCHITECTURES.values() if a != official)]
    misfits = []
    for candidate in candidates:
        if file_format == FORMAT_ANYSPLAT:
            candidate = _anysplat_architecture(path, candidate, used)
        try:
            _require_fits(path, candidate, fresh_modules, used)
        except InputError as error:
            misfits.append(error)
            continue
        return _Layout(file_format, candidate, provenance, names, ignored, fresh_modules)
    if architecture:
        raise InputError(f"{misfits[0]}. It was read as the '{architecture.name}' architecture; pass the one it was "
                         f"trained at ({', '.join(ARCHITECTURES)})") from None
    raise InputError(f"{misfits[0]}. It fits none of lumos3d's architectures ({', '.join(ARCHITECTURES)}); "
                     f"compared above with {OFFICIAL_ARCHITECTURE}, the official size") from None


@functools.lru_cache(maxsize=8)
def _network_shapes(architecture: Architecture) -> dict[str, tuple[int, ...]]:
    """The state-dict shapes of `architecture`'s network, built once on the meta device (no memory,
    no initialisation; 40-75 ms, which loading a model would otherwise pay twice)."""
    with torch.device("meta"):
        network = Lumos3D(architecture)
    return {key: tuple(tensor.shape) for key, tensor in network.state_dict().items()}


def _require_fits(path: Path, architecture: Architecture, fresh_modules: list[str], shapes: dict[str, tuple[int, ...]]) -> None:
    """InputError unless `shapes` (our parameter names) are exactly the network's of `architecture`,
    less the `fresh_modules` the file does not provide."""
    fresh = tuple(f"{name}." for name in fresh_modules)
    check_shapes({key: shape for key, shape in _network_shapes(architecture).items() if not key.startswith(fresh)},
                 shapes, str(path))


def _require_real_floats(path: Path, raw: dict[str, torch.Tensor], layout: _Layout) -> None:
    """InputError naming the first tensor the network takes that holds no real floating-point
    values (bool, integer, complex): every parameter of the network is float32, and loading
    such a tensor failed deep inside torch, or dropped a complex tensor's imaginary part."""
    for key in layout.names:
        tensor = raw[key]
        if not tensor.is_floating_point():
            raise InputError(f"{path}: tensor {key} holds {str(tensor.dtype).removeprefix('torch.')} values; the network's "
                             "weights are floating point: the file is damaged or not a checkpoint of this network")


def require_finite_weights(path: Path, tensors: dict[str, torch.Tensor]) -> None:
    """NonFiniteError naming the file and the first tensor holding NaN or Inf: such weights (a
    diverged or damaged save) would only surface later as a failure deep inside the network."""
    for key, tensor in tensors.items():
        require_finite(f"{path}: tensor {key}", tensor, "the checkpoint is damaged (e.g. saved by a diverged run); use another")


def read_checkpoint(path: Path | str, architecture: Architecture | None = None) -> Checkpoint:
    """Read any supported checkpoint (file, or folder holding one), checked against its network key
    by key and shape by shape. `architecture` gives the network size for foreign layouts (default:
    the first of ARCHITECTURES the file fits, vggt-1b tried first); our files carry their own.
    NaN or Inf in any tensor is an error naming the file and the tensor."""
    path = resolve_weights_file(Path(path))
    metadata, raw = read_weights(path)
    require_finite_weights(path, raw)
    layout = _interpret(path, {k: tuple(v.shape) for k, v in raw.items()}, metadata, architecture)
    _require_real_floats(path, raw, layout)
    tensors = {}
    for key, name in layout.names.items():
        tensor = raw[key]
        if tensor.is_floating_point() and tensor.dtype != torch.float32:
            wider = tensor.dtype == torch.float64  # float16 and bfloat16 always fit float32
            tensor = tensor.float()
            if wider and not torch.isfinite(tensor).all():  # finite in float64, beyond float32's range
                raise InputError(f"{path}: tensor {key} holds values up to {float(raw[key].abs().max()):.4g}, beyond the "
                                 f"float32 range lumos3d computes in (±{torch.finfo(torch.float32).max:.4g})")
        tensors[name] = tensor
    if layout.ignored:
        modules = ", ".join(sorted({k.split(".")[0] for k in layout.ignored}))
        logger.info("%s: ignored %d tensors not used by Lumos3D (%s)", path.name, len(layout.ignored), modules)
    return Checkpoint(path, layout.format, layout.architecture, tensors, layout.provenance, layout.ignored, layout.fresh_modules)


def read_provenance(path: Path | str) -> dict:
    """What a checkpoint file records of how it was made (its training steps, stage ...), from its
    header alone: no weight is read."""
    path = resolve_weights_file(Path(path))
    shapes, metadata = read_header(path)
    return _interpret(path, shapes, metadata, None).provenance


def summarize_checkpoint(path: Path | str, architecture: Architecture | None = None) -> dict:
    """Format, architecture, parameter count, tensor names by module, dtypes (of the tensors used,
    by torch's names) and provenance (for `lumos3d info`). The file is checked as loading checks
    it: NaN or Inf, and every key and shape against the architecture (`architecture` for a foreign
    file, as in `read_checkpoint`); one read at disk speed: seconds for VGGT-1B."""
    path = resolve_weights_file(Path(path))
    metadata, raw = read_weights(path)
    require_finite_weights(path, raw)
    layout = _interpret(path, {key: tuple(tensor.shape) for key, tensor in raw.items()}, metadata, architecture)
    _require_real_floats(path, raw, layout)
    used = {name: tuple(raw[key].shape) for key, name in layout.names.items()}
    modules = Counter(name.split(".")[0] for name in used)
    dtypes = Counter(str(raw[key].dtype).removeprefix("torch.") for key in layout.names)
    parameters = sum(int(torch.Size(shape).numel()) for shape in used.values())
    return {
        "kind": "checkpoint",
        "path": str(path),
        "file_bytes": path.stat().st_size,
        "format": layout.format,
        "architecture": layout.architecture.name,
        "sh_degree": layout.architecture.sh_degree,
        "voxel_size": layout.architecture.voxel_size,
        "image_size": layout.architecture.image_size,
        "parameters": parameters,
        "tensors": len(used),
        "modules": dict(sorted(modules.items())),
        "dtypes": dict(sorted(dtypes.items())),
        "ignored_tensors": len(layout.ignored),
        "fresh_modules": layout.fresh_modules,
        "provenance": layout.provenance,
    }
