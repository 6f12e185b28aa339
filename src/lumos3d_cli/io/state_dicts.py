"""Read weight files safely (safetensors, or torch files with weights_only=True: no pickled code
runs) and check them strictly against the tensors a network expects."""

from __future__ import annotations

import pickle
import warnings
import zipfile
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError

_SHOWN_KEYS = 4  # keys listed per problem in error messages (one line stays readable)


def listing(names: list[str]) -> str:
    shown = ", ".join(names[:_SHOWN_KEYS])
    return shown + (f" ... and {len(names) - _SHOWN_KEYS} more" if len(names) > _SHOWN_KEYS else "")


def check_shapes(expected: dict[str, tuple[int, ...]], found: dict[str, tuple[int, ...]], source: str) -> None:
    """Strict check of a file's tensor shapes (`found`, by key) against a network's (`expected`):
    the same key set and every shape equal; else InputError listing the missing, unexpected and
    mis-shaped keys (at most _SHOWN_KEYS of each)."""
    missing = sorted(set(expected) - set(found))
    unexpected = sorted(set(found) - set(expected))
    mismatched = sorted(
        f"{key} (file {tuple(found[key])}, model {tuple(expected[key])})"
        for key in set(expected) & set(found)
        if tuple(found[key]) != tuple(expected[key])
    )
    problems = []
    if missing:
        problems.append(f"{len(missing)} missing keys: {listing(missing)}")
    if unexpected:
        problems.append(f"{len(unexpected)} unexpected keys: {listing(unexpected)}")
    if mismatched:
        problems.append(f"{len(mismatched)} keys of the wrong shape: {listing(mismatched)}")
    if problems:
        raise InputError(f"{source}: does not fit the model; " + "; ".join(problems))


def read_state_dict(path: Path | str) -> dict[str, torch.Tensor]:
    """A name -> tensor mapping from .safetensors or a torch file (a training checkpoint's
    "model" or "state_dict" entry is unwrapped). InputError for anything else."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give the weight file itself")
    if not path.is_file():
        raise InputError(f"{path}: weight file not found")
    if path.suffix.lower() == ".safetensors":
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        try:
            return load_file(str(path))
        except (SafetensorError, OSError) as error:
            raise InputError(f"{path}: cannot read as safetensors ({error})") from None
    return load_torch_state_dict(path)


# torch.save stores its archive's entries uncompressed; a compressed entry that expands this much
# (and beyond _MAX_EXPANDED_BYTES) is a zip bomb, which torch.load would expand in memory before
# any key is checked (a 1 MB file took 1.4 GB for `info`)
_MAX_EXPANSION = 100
_MAX_EXPANDED_BYTES = 64 << 20


def _refuse_a_zip_bomb(path: Path) -> None:
    """InputError when `path` is a zip archive holding a compressed entry that expands more than
    _MAX_EXPANSION-fold to over _MAX_EXPANDED_BYTES; anything else (not a zip, damaged) is left
    to torch.load to judge."""
    try:
        with zipfile.ZipFile(path) as archive:
            entries = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError):
        return
    for entry in entries:
        if (entry.compress_type != zipfile.ZIP_STORED and entry.file_size > _MAX_EXPANDED_BYTES
                and entry.file_size > _MAX_EXPANSION * max(1, entry.compress_size)):
            raise InputError(f"{path}: entry {entry.filename} expands {entry.file_size / max(1, entry.compress_size):.0f}-fold "
                             f"to {entry.file_size / 2**30:.2f} GiB; torch.save compresses nothing, so this is no "
                             "checkpoint it wrote (a zip bomb?): lumos3d does not load it")


def load_torch_state_dict(path: Path) -> dict[str, torch.Tensor]:
    _refuse_a_zip_bomb(path)
    try:
        with warnings.catch_warnings():  # torch's warnings about a raw pickle's protocol: the error below says it
            warnings.simplefilter("ignore")
            try:
                loaded = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
            except RuntimeError:
                # Files saved with the legacy (non-zip) serialisation cannot be memory-mapped.
                loaded = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        # torch explains weights_only over a paragraph; its own reason is the last line before the advice
        reasons = [line.strip() for line in str(error).splitlines() if line.strip() and not line.startswith(
            ("Weights only load failed", "Please file an issue", "Check the documentation"))]
        reason = reasons[-1] if reasons else type(error).__name__
        raise InputError(f"{path}: damaged, or holds objects other than tensors, which lumos3d does not unpickle "
                         f"({reason})") from None
    except Exception as error:  # unpickling arbitrary bytes fails in arbitrary ways (IndexError, KeyError...)
        detail = str(error).strip().splitlines()[0] if str(error).strip() else ""
        raise InputError(f"{path}: cannot read as a torch checkpoint: not a file torch.save wrote, or damaged "
                         f"({type(error).__name__}{': ' + detail if detail else ''})") from None
    for wrapper in ("model", "state_dict"):  # training checkpoints wrap the state dict
        if isinstance(loaded, dict) and isinstance(loaded.get(wrapper), dict):
            loaded = loaded[wrapper]
    if not isinstance(loaded, dict) or not all(isinstance(v, torch.Tensor) for v in loaded.values()):
        raise InputError(f"{path}: is not a state dict (a mapping of names to tensors)")
    named_otherwise = [repr(key) for key in loaded if not isinstance(key, str)]
    if named_otherwise:
        raise InputError(f"{path}: is not a state dict: keys must be names (text), not {listing(named_otherwise)}")
    sparse = sorted(key for key, tensor in loaded.items() if tensor.layout != torch.strided)
    if sparse:
        raise InputError(f"{path}: holds sparse tensors ({listing(sparse)}); save the weights as dense tensors "
                         "(.to_dense())")
    return loaded
