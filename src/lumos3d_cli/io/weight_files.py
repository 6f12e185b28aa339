"""Weight files on disk, whatever network they hold: find the file (a folder such as a Hugging Face
snapshot holds one), read its tensors and safetensors metadata, read only its header, and write
tensors atomically in a storage precision. What the keys mean is the model's business
(`model/checkpoints.py`). Nothing is ever unpickled beyond plain tensors
(`torch.load(weights_only=True)`).
"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file, save_file

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import atomic_path
from lumos3d_cli.io.state_dicts import load_torch_state_dict
from lumos3d_cli.io.weight_dtypes import STORAGE_DTYPE_NAMES

TORCH_SUFFIXES = (".pt", ".pth", ".bin")
# Files looked for, in order, when a folder (e.g. a Hugging Face snapshot) is given.
FOLDER_FILES = ("model.safetensors", "model.pt", "pytorch_model.bin")
STORAGE_DTYPES = {name: getattr(torch, name) for name in STORAGE_DTYPE_NAMES}


def storage_dtype(name: str) -> torch.dtype:
    """The torch dtype of a storage precision name; InputError listing the choices otherwise."""
    if name not in STORAGE_DTYPES:
        raise InputError(f"storage dtype {name!r}: use one of {', '.join(STORAGE_DTYPES)}")
    return STORAGE_DTYPES[name]


def resolve_weights_file(path: Path) -> Path:
    """`path` itself, or the weight file inside the folder `path`; InputError if there is none."""
    if not path.exists():
        raise InputError(f"{path}: checkpoint not found")
    if path.is_dir():
        for name in FOLDER_FILES:
            if (path / name).is_file():
                return path / name
        written = [name for name in ("selected.safetensors", "final.safetensors") if (path / name).is_file()]
        if (path / "run.json").is_file() or written:  # a training run's folder: point to its weights
            hint = f"; give {path / written[0]}" if written else "; give one of its checkpoints/step_* folders"
            raise InputError(f"{path}: a training run's folder, not a checkpoint{hint}")
        raise InputError(f"{path}: folder holds none of {', '.join(FOLDER_FILES)}")
    if not _is_safetensors(path) and path.suffix.lower() not in TORCH_SUFFIXES:
        raise InputError(f"{path}: not a checkpoint; expected .safetensors or a torch state dict ({', '.join(TORCH_SUFFIXES)})")
    return path


def _is_safetensors(path: Path) -> bool:
    return path.suffix.lower() == ".safetensors"


def _read_metadata(path: Path) -> dict[str, str]:
    try:
        with safe_open(str(path), framework="pt") as handle:
            return handle.metadata() or {}
    except (SafetensorError, OSError) as error:
        raise InputError(f"{path}: cannot read as safetensors ({error})") from None


def read_weights(path: Path) -> tuple[dict[str, str], dict[str, torch.Tensor]]:
    """(safetensors header metadata, empty for torch files; every tensor by its file key)."""
    if not _is_safetensors(path):
        return {}, load_torch_state_dict(path)
    metadata = _read_metadata(path)
    try:
        return metadata, load_file(str(path))
    except (SafetensorError, OSError) as error:
        raise InputError(f"{path}: cannot read as safetensors ({error})") from None


def read_header(path: Path) -> tuple[dict[str, tuple[int, ...]], dict[str, str]]:
    """(shapes, metadata) without loading tensor data where the format allows."""
    if _is_safetensors(path):
        metadata = _read_metadata(path)
        with safe_open(str(path), framework="pt") as handle:
            shapes = {key: tuple(handle.get_slice(key).get_shape()) for key in handle.keys()}
        return shapes, metadata
    return {k: tuple(v.shape) for k, v in load_torch_state_dict(path).items()}, {}


def write_weights(tensors: dict[str, torch.Tensor], path: Path, metadata: dict[str, str], dtype: str = "float32") -> Path:
    """Write `tensors` as one .safetensors file (atomically) with header `metadata`. Floating-point
    tensors are stored in `dtype` ("float16" halves the file); a value beyond that range is an
    InputError naming the tensor, never a silent infinity; NaN or Inf weights are a
    NonFiniteError naming the tensor."""
    if path.suffix != ".safetensors":
        raise InputError(f"{path}: checkpoints are written as .safetensors files")
    storage = storage_dtype(dtype)
    stored = {}
    for name, tensor in tensors.items():
        tensor = tensor.detach().to("cpu", torch.float32 if tensor.is_floating_point() else tensor.dtype)
        if tensor.is_floating_point():  # a file no loader would accept (`read_checkpoint`) is not written
            require_finite(name, tensor, "the weights are damaged (a diverged training run?); nothing was written")
        if tensor.is_floating_point() and storage != torch.float32:
            limit = torch.finfo(storage).max
            largest = float(tensor.abs().max())
            if largest > limit:
                raise InputError(f"tensor {name} holds values up to {largest:.4g}, beyond the {dtype} range (±{limit:.4g}); "
                                 "store this checkpoint as float32")
            tensor = tensor.to(storage)
        stored[name] = tensor.contiguous()
    with atomic_path(path) as temporary:
        save_file(stored, str(temporary), metadata=metadata)
    return path
