"""Fixtures for the viewer tests: a small restore output folder, and a websocket client that
receives what a browser would (viser's wire format, decoded independently of viser's Python)."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

import msgspec
import numpy as np
import pytest
import torch
import viser
import zstandard
from websockets.sync.client import connect

from lumos3d_cli.io.colmap import write_colmap_model
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.io.transforms_json import write_transforms_json
from lumos3d_cli.render.camera_paths import orbit_from_gaussians

from factories import random_scene

SCENE_SIZE = 500
VIEWS = 3


@pytest.fixture
def restore_folder(tmp_path) -> Path:
    """What `lumos3d restore -o out/scene.ply` writes, small: scene.ply, cameras.json, colmap/
    with 4 sparse points, restored/ views, summary.json listing the input photos' paths."""
    folder = tmp_path / "out"
    folder.mkdir()
    gaussians = random_scene(SCENE_SIZE, 0, degree=1, dtype=torch.float32)
    write_ply(folder / "scene.ply", gaussians)
    cameras = orbit_from_gaussians(gaussians, VIEWS, 40, 30)
    cameras.names = [f"photo{i}.jpg" for i in range(VIEWS)]
    write_transforms_json(folder / "cameras.json", cameras)
    write_colmap_model(folder / "colmap", cameras)
    points = "".join(f"{i + 1} {0.1 * i} 0.2 3.0 {50 * i} 100 200 0.5 1 0 2 0\n" for i in range(4))
    (folder / "colmap" / "points3D.txt").write_text("# 3D point list\n" + points)
    (folder / "restored").mkdir()
    photos = tmp_path / "photos"
    photos.mkdir()
    for i, name in enumerate(cameras.names):
        write_image(folder / "restored" / f"photo{i}.png", np.full((30, 40, 3), 0.8, np.float32))
        write_image(photos / name, np.full((30, 40, 3), 0.05, np.float32))
    summary = {
        "scene": str(folder / "scene.ply"), "inputs": VIEWS, "views_used": VIEWS, "views": cameras.names,
        "input_paths": [str(photos / name) for name in cameras.names], "mode": "low-light", "preset": "fast",
        "gaussians": {"kept": SCENE_SIZE}, "seconds": {"network": 1.25, "total": 3.5},
        "metrics": {"mean": {"psnr": 21.234, "ssim": 0.7512}},
    }
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


def _decode_frame(frame: bytes) -> list[tuple[dict, list[bytes]]]:
    """One websocket frame -> [(message, its binary buffers)]. Layout (viser infra): u64 msgpack
    length, u64 zstd length, zstd(msgpack), then 8-byte aligned raw buffers."""
    packed_length = int.from_bytes(frame[8:16], "little")
    inner = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(frame[16:16 + packed_length]))
    buffers, offset = [], 16 + packed_length
    for length in inner["binaryBufferLengths"]:
        offset += (8 - offset % 8) % 8
        buffers.append(frame[offset:offset + length])
        offset += length
    return [(message, buffers) for message in inner["messages"]]


def binary_field(message: dict, buffers: list[bytes], *keys: str) -> np.ndarray:
    """A numpy field of a message: viser sends arrays as {"__binary_index", "dtype"}, which point into
    the binary buffers that follow the frame's messages."""
    value = message
    for key in keys:
        value = value[key]
    return np.frombuffer(buffers[value["__binary_index"]], dtype=np.dtype(value["dtype"]))


def receive_scene(url: str, timeout: float = 30.0) -> dict[str, list[tuple[dict, list[bytes]]]]:
    """Connect like a browser and collect every message of the initial scene replay, by type."""
    received: dict[str, list] = defaultdict(list)
    address = url.replace("http://", "ws://")
    with connect(address, subprotocols=[f"viser-v{viser.__version__}"], max_size=None, open_timeout=timeout) as socket:
        while "ReplayDoneMessage" not in received:
            for message, buffers in _decode_frame(socket.recv(timeout=timeout)):
                received[message["type"]].append((message, buffers))
    return received


def splats_received(received) -> np.ndarray:
    """[N, 8] uint32: the splat buffer a browser gets (xyz float32, reserved, covariance float16 x6, rgba)."""
    (message, buffers), = received["GaussianSplatsMessage"]
    return binary_field(message, buffers, "props", "buffer").reshape(-1, 8)


def markdown_received(received) -> str:
    """The panel text as last set (add_markdown sends it empty, then an update)."""
    updates = [m["updates"]["_markdown"] for m, _ in received["GuiUpdateMessage"] if "_markdown" in m["updates"]]
    return updates[-1] if updates else "\n".join(m["props"]["_markdown"] for m, _ in received["GuiMarkdownMessage"])


@pytest.fixture
def viser_wire() -> SimpleNamespace:
    """The websocket helpers above, for the test modules (conftest is not importable)."""
    return SimpleNamespace(receive_scene=receive_scene, splats=splats_received, markdown=markdown_received,
                           binary_field=binary_field, decode_frame=_decode_frame)
