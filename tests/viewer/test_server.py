import urllib.request
import time

import cv2
import msgspec
import numpy as np
import pytest
import viser
from websockets.sync.client import connect

from lumos3d_cli.io.gaussians import sh_dc_to_rgb
from lumos3d_cli.io.ply import read_ply
from lumos3d_cli.viewer.framing import frame_scene
from lumos3d_cli.viewer.scene_folder import load_viewer_scene
from lumos3d_cli.viewer.server import start_viewer
from lumos3d_cli.viewer.splats import covariances


@pytest.fixture
def viewer(restore_folder):
    running = start_viewer(restore_folder, port=0)
    yield running
    running.stop()


def test_the_browser_gets_every_splat_in_the_viewer_frame(viewer, restore_folder, viser_wire):
    received = viser_wire.receive_scene(viewer.url)
    splats = viser_wire.splats(received)
    gaussians = read_ply(restore_folder / "scene.ply")
    assert viewer.shown == viewer.total == len(splats) == len(gaussians) == 500
    frame = frame_scene(gaussians, load_viewer_scene(restore_folder).cameras)
    # Decode the browser's layout: xyz float32, 4 reserved bytes, covariance upper triangle
    # float16 x 6, rgba uint8.
    centres = splats[:, :3].copy().view(np.float32)
    np.testing.assert_allclose(centres, frame.points(gaussians.means), rtol=1e-6, atol=1e-5)
    triangle = splats[:, 4:7].copy().view(np.float16).astype(np.float64)
    expected = covariances(gaussians.quats.double(), gaussians.scales.double() * frame.scale).numpy()
    expected = expected.reshape(-1, 9)[:, [0, 1, 2, 4, 5, 8]]
    np.testing.assert_allclose(triangle, expected, rtol=2e-3, atol=2e-3 * np.abs(expected).max())
    rgba = splats[:, 7:8].copy().view(np.uint8).reshape(-1, 4)
    rgb = sh_dc_to_rgb(gaussians.sh[:, 0]).clamp(0, 1).numpy()
    assert np.abs(rgba[:, :3] / 255.0 - rgb).max() <= 1 / 255  # viser truncates to uint8
    assert np.abs(rgba[:, 3] / 255.0 - gaussians.opacities.numpy()).max() <= 1 / 255


def test_cameras_points_and_panel(viewer, viser_wire):
    received = viser_wire.receive_scene(viewer.url)
    frustums = [m for m, _ in received["CameraFrustumMessage"]]
    assert len(frustums) == 3 and all(m["props"]["_image_data"] is not None for m in frustums)
    (points, buffers), = received["PointCloudMessage"]
    assert len(viser_wire.binary_field(points, buffers, "props", "points")) == 4 * 3
    assert len(received["SetSceneNodeClickBindingsMessage"]) == 3
    markdown = viser_wire.markdown(received)
    for expected in ("scene.ply", "**500 Gaussians**", "3 cameras", "4 SfM points", "| PSNR (dB) vs reference | 21.23 |",
                     "| SSIM vs reference | 0.751 |", "| run | low-light · fast |", "network 1.2 s"):
        assert expected in markdown, markdown
    (dropdown, _), = received["GuiDropdownMessage"]
    assert dropdown["props"]["disabled"] is False and dropdown["value"] == "restored"


def _send(socket, message: dict) -> None:
    socket.send(msgspec.msgpack.encode(message))


def _browser(viewer, viser_wire):
    """A websocket that has received the scene and, like a browser, told its camera (viser counts
    a client as connected from then on): (socket, scene messages by type)."""
    socket = connect(viewer.url.replace("http://", "ws://"), subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
    received: dict[str, list] = {}
    while "ReplayDoneMessage" not in received:
        for message, buffers in viser_wire.decode_frame(socket.recv(timeout=10)):
            received.setdefault(message["type"], []).append((message, buffers))
    _send(socket, {"type": "ViewerCameraMessage", "wxyz": [1, 0, 0, 0], "position": [0, 0, -30], "fov": 1.0,
                   "near": 0.01, "far": 1000.0, "image_height": 480, "image_width": 640, "look_at": [0, 0, 0],
                   "up_direction": [0, -1, 0]})
    return socket, received


def _messages_until(socket, viser_wire, done, seconds: float = 10.0) -> list[tuple[dict, list[bytes]]]:
    """Messages the server sends until done(collected) holds."""
    collected, deadline = [], time.time() + seconds
    while not done(collected) and time.time() < deadline:
        try:
            collected += viser_wire.decode_frame(socket.recv(timeout=1))
        except TimeoutError:
            pass
    return collected


def _decode_image(data, buffers) -> np.ndarray:
    """A frustum's encoded photo (inline bytes or a binary buffer) -> [H, W, 3] uint8."""
    encoded = buffers[data["__binary_index"]] if isinstance(data, dict) else data
    return cv2.imdecode(np.frombuffer(encoded, np.uint8), cv2.IMREAD_COLOR)


def test_the_switch_puts_the_input_photos_in_the_frustums(viewer, viser_wire):
    socket, received = _browser(viewer, viser_wire)
    with socket:
        restored = [_decode_image(m["props"]["_image_data"], buffers) for m, buffers in received["CameraFrustumMessage"]]
        assert [abs(image.mean() - 204) < 2 for image in restored] == [True] * 3  # restored/ PNGs are 0.8 grey
        (dropdown, _), = received["GuiDropdownMessage"]

        def image_updates(messages):
            return [(m, b) for m, b in messages if m["type"] == "SceneNodeUpdateMessage" and "_image_data" in m["updates"]]

        _send(socket, {"type": "GuiUpdateMessage", "uuid": dropdown["uuid"], "updates": {"value": "input"}})
        updates = image_updates(_messages_until(socket, viser_wire, lambda got: len(image_updates(got)) >= 3))
        images = [_decode_image(m["updates"]["_image_data"], buffers) for m, buffers in updates]
        assert len(images) == 3 and all(image.mean() < 20 for image in images)  # the input photos are 0.05 grey


def test_clicking_a_frustum_moves_that_browsers_view_to_the_camera(viewer, viser_wire):
    socket, received = _browser(viewer, viser_wire)
    with socket:
        (target,) = [m["position"] for m, _ in received["SetPositionMessage"] if m["name"] == "/cameras/0001"]
        _send(socket, {"type": "SceneNodeClickMessage", "name": "/cameras/0001", "instance_index": None,
                       "ray_origin": [0, 0, -30], "ray_direction": [0, 0, 1], "screen_pos": [0.5, 0.5], "modifier": None})

        def moves(messages):
            return [m["position"] for m, _ in messages if m["type"] == "SetCameraPositionMessage" and not m.get("initial")]

        positions = moves(_messages_until(socket, viser_wire, moves))
    assert positions and np.allclose(positions[0], target, atol=1e-4)


def test_an_ipv6_address_is_announced_in_brackets(restore_folder):
    """`--host ::1` announced http://::1:PORT, which no browser or curl opens."""
    running = start_viewer(restore_folder, host="::1", port=0)
    try:
        assert running.url.startswith("http://[::1]:")
        with urllib.request.urlopen(running.url, timeout=10) as response:
            assert response.status == 200
    finally:
        running.stop()
