"""Gaussian scenes as INRIA 3DGS `.ply` files (binary little-endian float32).

Property order: x y z nx ny nz f_dc_0..2 f_rest_0..(3(K-1)-1) opacity scale_0..2 rot_0..3;
opacity stored as a logit, scales as logs, rotation as wxyz, f_rest channel-major (all of red's
higher-order coefficients, then green's, then blue's). Conversions run in float64 so that a scene
written once round-trips bit-exactly from then on (see docs/formats.md).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.errors import InputError, NonFiniteError, listed
from lumos3d_cli.io.atomic import atomic_path, warn_if_mid_commit
from lumos3d_cli.io.gaussians import MAX_SH_DEGREE, Gaussians, sh_coefficient_count
from lumos3d_cli.io.output_paths import require_new_file

# Opacity is clamped into the open interval before the logit so that 0 and 1 stay finite on disk.
_OPACITY_EPS = 2.0**-24
# Smallest scale written: log() of anything below stays finite and far below any visible footprint.
_MIN_SCALE = 1e-30

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": None}


def ply_property_names(sh_degree: int) -> list[str]:
    """Vertex property names in file order for a given SH degree."""
    rest = 3 * (sh_coefficient_count(sh_degree) - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def gaussians_to_ply_fields(gaussians: Gaussians) -> np.ndarray:
    """Gaussians -> [N, P] float32 in the order of `ply_property_names`."""
    gaussians.require_finite("scene to save")
    gaussians.require_activated("scene to save")
    gaussians.require_float32_range("scene to save")
    g = gaussians.detach().to(device="cpu", dtype=torch.float64)
    n, k = len(g), g.sh.shape[1]
    opacity = g.opacities.clamp(_OPACITY_EPS, 1 - _OPACITY_EPS)
    columns = [
        g.means,
        torch.zeros(n, 3, dtype=torch.float64),
        g.sh[:, 0, :],
        g.sh[:, 1:, :].transpose(1, 2).reshape(n, 3 * (k - 1)),
        torch.log(opacity / (1 - opacity))[:, None],
        torch.log(g.scales.clamp_min(_MIN_SCALE)),
        g.quats,
    ]
    return torch.cat(columns, dim=1).numpy().astype(np.float32)


_NORMALS = ("nx", "ny", "nz")
_MAX_LOG_SCALE = float(np.log(np.finfo(np.float32).max))  # 88.7: exp of more is Inf in float32


def ply_fields_to_gaussians(fields: np.ndarray, sh_degree: int) -> Gaussians:
    """[N, P] float values in the order of `ply_property_names` -> Gaussians (float32)."""
    values = torch.from_numpy(np.ascontiguousarray(fields, dtype=np.float64))
    n, k = values.shape[0], sh_coefficient_count(sh_degree)
    rest_end = 9 + 3 * (k - 1)
    dc = values[:, 6:9]
    rest = values[:, 9:rest_end].reshape(n, 3, k - 1).transpose(1, 2)
    gaussians = Gaussians(
        means=values[:, 0:3],
        quats=values[:, rest_end + 4 : rest_end + 8],
        scales=torch.exp(values[:, rest_end + 1 : rest_end + 4]),
        opacities=torch.sigmoid(values[:, rest_end]),
        sh=torch.cat([dc[:, None, :], rest], dim=1),
    )
    return gaussians.to(torch.float32)


def write_ply(path: Path | str, gaussians: Gaussians, overwrite: bool = False) -> None:
    """Write the scene atomically, to a new file unless `overwrite` (an existing one is an
    InputError). NaN or Inf in any tensor is an error naming the tensor."""
    path = Path(path)
    require_new_file(path, overwrite)
    names = ply_property_names(gaussians.sh_degree)
    values = gaussians_to_ply_fields(gaussians)
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", "comment written by lumos3d", f"element vertex {len(gaussians)}"]
        + [f"property float {name}" for name in names]
        + ["end_header"]
    ) + "\n"
    with atomic_path(path) as temporary, open(temporary, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(values.astype("<f4", copy=False).tobytes())


def _parse_header(path: Path, handle) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    """Return (format, elements) where each element is (name, count, [(property, dtype code)])."""
    if handle.readline().strip() != b"ply":
        raise InputError(f"{path}: not a PLY file (missing 'ply' magic line)")
    file_format = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    while True:
        raw = handle.readline()
        if not raw:
            raise InputError(f"{path}: PLY header has no 'end_header' line; the file is truncated or corrupt")
        words = raw.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            if len(words) < 2 or words[1] not in _FORMATS:
                raise InputError(f"{path}: unknown PLY format line {' '.join(words)!r}")
            file_format = words[1]
        elif words[0] == "element" and len(words) == 3 and re.fullmatch(r"\d+", words[2]):
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                raise InputError(f"{path}: element '{elements[-1][0]}' has list properties; not a Gaussian scene")
            if len(words) != 3 or words[1] not in _PLY_TYPES:
                raise InputError(f"{path}: cannot parse PLY header line {' '.join(words)!r}")
            if any(name == words[2] for name, _ in elements[-1][2]):
                raise InputError(f"{path}: PLY header lists property {words[2]!r} of '{elements[-1][0]}' twice; the "
                                 "file is corrupt")
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise InputError(f"{path}: cannot parse PLY header line {' '.join(words)!r}")
    if file_format is None:
        raise InputError(f"{path}: PLY header has no 'format' line")
    return file_format, elements


def _sh_degree_from_properties(path: Path, names: set[str]) -> int:
    rest = sum(1 for name in names if name.startswith("f_rest_"))
    for degree in range(MAX_SH_DEGREE + 1):
        if rest == 3 * (sh_coefficient_count(degree) - 1):
            return degree
    raise InputError(
        f"{path}: {rest} f_rest_* properties do not match any SH degree 0-{MAX_SH_DEGREE} "
        "(expected 0, 9, 24, 45 or 72)"
    )


def read_ply_fields(path: Path | str) -> tuple[np.ndarray, int]:
    """Read a Gaussian `.ply` into ([N, P] float32 in `ply_property_names` order, SH degree).

    Properties may come in any order and type; extra properties are ignored; missing ones are
    an InputError that lists them.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give the scene's .ply file (e.g. {path / 'scene.ply'})")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    with open(path, "rb") as handle:
        file_format, elements = _parse_header(path, handle)
        if not elements or elements[0][0] != "vertex":
            raise InputError(f"{path}: first PLY element must be 'vertex' (found {[e[0] for e in elements]})")
        _, count, properties = elements[0]
        present = {name for name, _ in properties}
        degree = _sh_degree_from_properties(path, present)
        wanted = ply_property_names(degree)
        missing = [name for name in wanted if name not in present and name not in _NORMALS]
        if missing:
            raise InputError(
                f"{path}: not a 3D Gaussian scene; missing vertex properties: {', '.join(missing)}"
            )
        byte_order = _FORMATS[file_format]
        if byte_order is None:
            try:
                table = (np.loadtxt(handle, dtype=np.float64, max_rows=count, ndmin=2) if count
                         else np.zeros((0, len(properties))))
            except ValueError as error:
                raise InputError(f"{path}: ASCII PLY data is not numbers ({error})") from None
            if table.shape != (count, len(properties)):
                raise InputError(f"{path}: ASCII PLY has {table.shape[0]} rows of {table.shape[1]} values, "
                                 f"expected {count} of {len(properties)}")
            columns = {name: table[:, i] for i, (name, _) in enumerate(properties)}
        else:
            dtype = np.dtype([(name, byte_order + code) for name, code in properties])
            needed = dtype.itemsize * count
            left = max(0, os.fstat(handle.fileno()).st_size - handle.tell())  # before reading: a count can claim petabytes
            if left < needed:
                raise InputError(f"{path}: PLY data is truncated ({left} of {needed} bytes for {count} Gaussians)")
            records = np.frombuffer(handle.read(needed), dtype=dtype, count=count)
            columns = {name: records[name] for name, _ in properties}
    largest = float(np.finfo(np.float32).max)
    for name in wanted:  # a float64 file's value beyond float32 became Inf in the cast (numpy's warning, then "Inf")
        values = columns.get(name)
        if values is not None and values.dtype.kind == "f" and values.dtype.itemsize == 8:  # '>f8' too
            beyond = np.isfinite(values) & (np.abs(values) > largest)
            if beyond.any():
                raise InputError(f"{path}: property {name} holds values up to {float(np.abs(values[beyond]).max()):.4g}, "
                                 f"beyond the float32 range lumos3d computes in (±{largest:.4g})")
    zeros = np.zeros(count, dtype=np.float32)
    table = np.stack([columns[name] if name in columns else zeros for name in wanted], axis=1).astype(np.float32)
    return table, degree


def _unusable(table: np.ndarray, degree: int) -> np.ndarray:
    """[N, P] bool: the values of `table` (in `ply_property_names(degree)` order) that no scene can
    use: NaN or Inf (normals aside: nothing reads them; an Inf opacity or a -Inf scale activates
    to a finite value, so they are found here, in the file's values) and log-scales whose exp
    overflows float32."""
    names = ply_property_names(degree)
    unusable = ~np.isfinite(table)
    unusable[:, [names.index(name) for name in _NORMALS]] = False
    scales = [names.index(f"scale_{axis}") for axis in range(3)]
    unusable[:, scales] |= np.nan_to_num(table[:, scales], nan=0.0) > _MAX_LOG_SCALE
    return unusable


def unusable_values(table: np.ndarray, degree: int) -> dict[str, int]:
    """{property: how many of its values no scene can use} (see `_unusable`), for the properties
    that hold any."""
    counts = _unusable(table, degree).sum(axis=0)
    return {name: int(count) for name, count in zip(ply_property_names(degree), counts) if count}


def usable_rows(table: np.ndarray, degree: int) -> np.ndarray:
    """[N] bool: the Gaussians of `table` whose values a scene can use."""
    return ~_unusable(table, degree).any(axis=1)


def read_ply(path: Path | str) -> Gaussians:
    """Read a Gaussian `.ply` (any 3DGS-layout file) into activated Gaussians. NaN or Inf in a
    property a scene uses, or a log-scale whose exp overflows, is an error naming the file and the
    properties (`info` counts them instead)."""
    warn_if_mid_commit(path)
    table, degree = read_ply_fields(path)
    names = ply_property_names(degree)
    log_scales = table[:, [names.index(f"scale_{axis}") for axis in range(3)]]
    largest = float(np.nanmax(log_scales, initial=-np.inf))
    if math.isfinite(largest) and largest > _MAX_LOG_SCALE:  # finite in the file, Inf once activated
        raise InputError(f"{path}: holds log-scales (scale_*) up to {largest:g}, a Gaussian larger than float32 holds "
                         f"(exp overflows above {_MAX_LOG_SCALE:.1f}); correct or drop those Gaussians")
    unusable = unusable_values(table, degree)
    if unusable:
        raise NonFiniteError(f"{path}: {sum(unusable.values())} value(s) no scene can use, NaN, Inf or log-scales above "
                             f"{_MAX_LOG_SCALE:.1f} ({listed([f'{name}: {count}' for name, count in unusable.items()], 4)}); "
                             "correct or drop those Gaussians")
    gaussians = ply_fields_to_gaussians(table, degree)
    gaussians.require_finite(f"{path}: gaussians")
    return gaussians
