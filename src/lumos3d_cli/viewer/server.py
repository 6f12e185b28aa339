"""`lumos3d view`'s server: the scene as splats in a viser page, cameras as clickable frustums
showing the input or restored photo, the SfM points, and a summary panel.

viser serves its prebuilt web client from inside its wheel, so the viewer works offline."""

from __future__ import annotations

import contextlib
import io
import logging
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import viser

from lumos3d_cli.errors import InputError
from lumos3d_cli.viewer.defaults import DEFAULT_HOST, DEFAULT_PORT
from lumos3d_cli.viewer.framing import VIEWER_RADIUS, ViewerFrame, frame_scene, view_position_showing
from lumos3d_cli.viewer.panel import panel_markdown
from lumos3d_cli.viewer.port import port_in_use, require_free_port
from lumos3d_cli.viewer.scene_folder import ViewerScene, load_viewer_scene
from lumos3d_cli.viewer.splats import DEFAULT_MAX_SPLATS, splat_arrays

logger = logging.getLogger(__name__)

_PHOTO_CHOICES = ("restored", "input")
_POINT_SIZE = 0.004 * VIEWER_RADIUS
_FRUSTUM_COLOUR = (255, 160, 40)


@dataclass
class RunningViewer:
    """A started viewer: `url` to open, `shown` splats sent to browsers; `stop()` frees the port."""

    server: viser.ViserServer
    url: str
    shown: int
    total: int

    def stop(self) -> None:
        with viser_output_to_log():
            self.server.stop()


@contextlib.contextmanager
def viser_output_to_log() -> Iterator[None]:
    """viser prints a banner when it starts and a line when it stops on stdout, which carries
    only our results; send those lines to the debug log instead."""
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        yield
    for line in captured.getvalue().splitlines():
        if line.strip():
            logger.debug("viser: %s", line)


def _frustum_scale(positions: np.ndarray) -> float:
    """Frustum size in viewer units: half the median spacing of neighbouring cameras, kept
    between 3 % and 8 % of the scene radius so that frustums neither vanish nor cover the scene."""
    if len(positions) > 1:
        distances = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
        np.fill_diagonal(distances, np.inf)
        spacing = float(np.median(distances.min(axis=1)))
    else:
        spacing = math.inf
    return float(np.clip(0.5 * spacing, 0.03 * VIEWER_RADIUS, 0.08 * VIEWER_RADIUS))


def _vertical_fov(intrinsics: np.ndarray, height: int) -> float:
    """Radians, from fy [3, 3] and the image height in pixels."""
    return 2.0 * math.atan(height / (2.0 * float(intrinsics[1, 1])))


def _set_initial_view(server: viser.ViserServer, scene: ViewerScene, frame: ViewerFrame) -> None:
    """Start behind and above the cameras, far enough back to show them all, looking at the scene
    centre (or in front of a bare scene)."""
    up = frame.up
    if scene.cameras is not None and len(scene.cameras):
        wxyz, positions = frame.camera_poses(scene.cameras)
        forwards = np.stack([viser.transforms.SO3(q).as_matrix()[:, 2] for q in wxyz])
        forward = forwards.mean(axis=0)
        forward /= max(np.linalg.norm(forward), 1e-9)
        right = np.cross(forward, -up)
        right /= max(np.linalg.norm(right), 1e-9)
        # Oblique, so that relief shows: a view along the cameras' axis looks like a flat photo.
        behind_cameras = positions.mean(axis=0) + VIEWER_RADIUS * (-0.5 * forward + 0.3 * up + 0.4 * right)
        width, height = scene.cameras.sizes[0]
        fov = _vertical_fov(scene.cameras.intrinsics[0].numpy(), height)
        position = view_position_showing(positions, behind_cameras, up, fov)
    else:
        # World frame = first camera (OpenCV): the scene lies along +z.
        position = np.array([0.0, 0.0, -2.5 * VIEWER_RADIUS]) + 0.5 * VIEWER_RADIUS * up
        fov = math.radians(50.0)
    server.initial_camera.position = position
    server.initial_camera.look_at = (0.0, 0.0, 0.0)
    server.initial_camera.up = up
    server.initial_camera.fov = fov


def _add_cameras(server: viser.ViserServer, scene: ViewerScene, frame: ViewerFrame) -> list:
    """One frustum per camera with its restored photo; a click moves that browser's view there."""
    cameras = scene.cameras
    wxyz, positions = frame.camera_poses(cameras)
    scale = _frustum_scale(positions)
    frustums = []
    for index in range(len(cameras)):
        width, height = cameras.sizes[index]
        fov = _vertical_fov(cameras.intrinsics[index].numpy(), height)
        name = cameras.names[index] or f"{index:05d}"
        frustum = server.scene.add_camera_frustum(
            f"/cameras/{index:04d}", fov=fov, aspect=width / height, scale=scale, color=_FRUSTUM_COLOUR,
            thickness=0.03 * scale, image=scene.restored[index], format="jpeg", jpeg_quality=85,
            wxyz=wxyz[index], position=positions[index],
        )

        def look_through(event: viser.SceneNodePointerEvent, frustum=frustum, fov=fov) -> None:
            forward = viser.transforms.SO3(frustum.wxyz).as_matrix()[:, 2]
            # Orbit around the scene centre's depth afterwards, not around the camera itself.
            depth = max(float(np.dot(-np.asarray(frustum.position), forward)), 0.1 * VIEWER_RADIUS)
            with event.client.atomic():
                event.client.camera.position = frustum.position
                event.client.camera.wxyz = frustum.wxyz
                event.client.camera.look_at = np.asarray(frustum.position) + depth * forward
                event.client.camera.fov = fov
            logger.debug("view moved to camera %s", name)

        frustum.on_click(look_through)
        frustums.append(frustum)
    return frustums


def _add_panel(server: viser.ViserServer, scene: ViewerScene, shown: int, max_splats: int, splats, frustums, points) -> None:
    server.gui.add_markdown(panel_markdown(scene, shown, max_splats))
    splat_switch = server.gui.add_checkbox("Gaussians", True)
    splat_switch.on_update(lambda _: setattr(splats, "visible", splat_switch.value))
    if frustums:
        camera_switch = server.gui.add_checkbox("Cameras", True)
        camera_switch.on_update(lambda _: [setattr(f, "visible", camera_switch.value) for f in frustums])
        has_inputs = any(image is not None for image in scene.inputs)
        photos = server.gui.add_dropdown(
            "Photos in cameras", _PHOTO_CHOICES, initial_value="restored", disabled=not has_inputs,
            hint="The restored view or the photo it came from." if has_inputs else "summary.json lists no input photos.",
        )

        def show_photos(_) -> None:
            chosen = scene.inputs if photos.value == "input" else scene.restored
            for frustum, image, fallback in zip(frustums, chosen, scene.restored):
                frustum.image = image if image is not None else fallback

        photos.on_update(show_photos)
    if points is not None:
        point_switch = server.gui.add_checkbox("SfM points", True)
        point_switch.on_update(lambda _: setattr(points, "visible", point_switch.value))


def build_viewer(server: viser.ViserServer, scene: ViewerScene, max_splats: int = DEFAULT_MAX_SPLATS) -> int:
    """Put `scene` into `server` (splats, frustums, points, panel); returns the splats sent."""
    frame = frame_scene(scene.gaussians, scene.cameras)
    # A dark background, as the restored views are rendered on black: semi-transparent splats
    # over viser's default white would look paler than the scene is.
    server.gui.configure_theme(dark_mode=True, control_width="large")
    server.scene.set_up_direction(frame.up)
    _set_initial_view(server, scene, frame)
    arrays = splat_arrays(scene.gaussians, frame.centre, frame.scale, max_splats)
    splats = server.scene.add_gaussian_splats(
        "/scene", centers=arrays.centers, covariances=arrays.covariances, rgbs=arrays.rgbs, opacities=arrays.opacities,
    )
    frustums = _add_cameras(server, scene, frame) if scene.cameras is not None else []
    points = None
    if scene.points is not None:
        points = server.scene.add_point_cloud(
            "/sfm_points", points=frame.points(scene.points.xyz), colors=scene.points.rgb,
            point_size=_POINT_SIZE, precision="float32",
        )
    _add_panel(server, scene, len(arrays), max_splats, splats, frustums, points)
    return len(arrays)


def start_viewer(
    path: Path | str, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, max_splats: int = DEFAULT_MAX_SPLATS
) -> RunningViewer:
    """Load `path` (restore output folder or .ply), start serving it and return at once."""
    if max_splats < 1:
        raise InputError(f"{max_splats}: use at least 1", parameter="max_splats")
    scene = load_viewer_scene(path)
    require_free_port(host, port)
    with viser_output_to_log():
        server = viser.ViserServer(host=host, port=port, label="lumos3d", verbose=False)
    bound = server.get_port()
    if port != 0 and bound != port:
        # Another program took the port between our check and viser's bind.
        RunningViewer(server, "", 0, 0).stop()
        raise port_in_use(host, port)
    shown_host = "localhost" if host in ("0.0.0.0", "::") else f"[{host}]" if ":" in host else host  # IPv6 in brackets
    viewer = RunningViewer(server, f"http://{shown_host}:{bound}", 0, len(scene.gaussians))
    try:
        viewer.shown = build_viewer(server, scene, max_splats)
    except BaseException:
        viewer.stop()
        raise
    return viewer


def serve_scene(
    path: Path | str,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    max_splats: int = DEFAULT_MAX_SPLATS,
    on_ready: Callable[[RunningViewer], None] | None = None,
) -> None:
    """Serve `path` until Ctrl-C, then stop the server and return (callers exit with 130).

    on_ready(viewer) runs once the page is up, e.g. to print viewer.url."""
    viewer = start_viewer(path, host, port, max_splats)
    try:
        if on_ready is not None:
            on_ready(viewer)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        logger.debug("viewer interrupted")
    finally:
        viewer.stop()
