import json
from dataclasses import replace
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import torch

from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.io.transforms_json import write_transforms_json
from lumos3d_cli.render.camera_paths import orbit_from_gaussians
from lumos3d_cli.render.render import render

from factories import random_scene
from assertions import expect_input_error
from output_files import listing


def _scene(tmp_path):
    gaussians = random_scene(400, 0, degree=1, dtype=torch.float32, spread=0.4)
    folder = tmp_path / "scene"
    folder.mkdir()
    write_ply(folder / "scene.ply", gaussians)
    return folder / "scene.ply", gaussians


def test_render_from_poses_matches_the_library(run_cli, tmp_path):
    path, gaussians = _scene(tmp_path)
    cameras = orbit_from_gaussians(gaussians, 3, 48, 32)
    write_transforms_json(tmp_path / "cameras.json", cameras)
    result = run_cli("render", path, "--poses", tmp_path / "cameras.json", "-o", tmp_path / "views", "--json",
                     "--background", "0.2,0.4,0.6")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["frames"] == 3 and (summary["width"], summary["height"]) == (48, 32)
    assert listing(tmp_path / "views") == ["00000.png", "00001.png", "00002.png"]
    written = cv2.imread(str(tmp_path / "views" / "00001.png"))[..., ::-1] / 255.0
    from lumos3d_cli.io.ply import read_ply

    expected = render(read_ply(path), cameras[1], background=(0.2, 0.4, 0.6)).images[0].permute(1, 2, 0).numpy()
    assert np.abs(written - expected).max() <= 0.5 / 255 + 1e-6


def test_filled_frames_are_restores_views_and_plain_ones_their_render_over_black(run_cli, tmp_path, buu, random_checkpoint):
    """restore's views are filled renders (render.hole_filling); `render --fill-unobserved` at the
    written cameras reproduces them, the plain render is the library's over black."""
    from lumos3d_cli.io.camera_files import read_cameras
    from lumos3d_cli.io.ply import read_ply
    from lumos3d_cli.render.hole_filling import fill_unobserved

    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("1.JPG", "4.JPG", "7.JPG"):
        (photos / name).write_bytes((buu / "low" / name).read_bytes())
    out = tmp_path / "out" / "scene.ply"
    assert run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--preset", "fast").code == 0
    filled = run_cli("render", out, "--poses", out.parent / "cameras.json", "-o", tmp_path / "filled", "--fill-unobserved",
                     "--json")
    assert filled.code == 0, filled.err
    assert json.loads(filled.out)["filled"] is True
    assert run_cli("render", out, "--poses", out.parent / "cameras.json", "-o", tmp_path / "plain").code == 0
    gaussians, cameras = read_ply(out), read_cameras(out.parent / "cameras.json")
    for index, name in enumerate(cameras.names):
        view = cv2.imread(str(out.parent / "restored" / (name.rsplit(".", 1)[0] + ".png"))).astype(int)
        assert np.abs(cv2.imread(str(tmp_path / "filled" / f"{index:05d}.png")).astype(int) - view).max() <= 1
        with torch.no_grad():
            output = render(gaussians, cameras[[index]])
        expected = fill_unobserved(output.images[0], output.alphas[0]).image  # the oracle of the filled frame's rule
        assert np.abs(np.round(expected.permute(1, 2, 0).numpy()[..., ::-1] * 255) - view).max() <= 1
        plain = np.round(output.images[0].clamp(0, 1).permute(1, 2, 0).numpy()[..., ::-1] * 255)
        assert np.abs(cv2.imread(str(tmp_path / "plain" / f"{index:05d}.png")).astype(int) - plain).max() <= 1
    expect_input_error(run_cli("render", out, "--orbit", 2, "-o", tmp_path / "x", "--fill-unobserved", "--background",
                               "1,1,1"), "--background 1,1,1: a filled frame shows no background")


def test_render_orbit_around_cameras_beside_the_scene_with_video(run_cli, tmp_path):
    path, gaussians = _scene(tmp_path)
    write_transforms_json(path.parent / "cameras.json", orbit_from_gaussians(gaussians, 4, 64, 48))
    result = run_cli("render", path, "--orbit", 6, "-o", tmp_path / "frames", "--video", tmp_path / "orbit.mp4",
                     "--width", 32, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["cameras"].startswith("orbit around the cameras") and (summary["width"], summary["height"]) == (32, 24)
    assert summary["video"] | {"path": None} == {"path": None, "codec": "h264", "pixel_format": "yuv420p",
                                                 "width": 32, "height": 24, "frames": 6, "fps": 30}
    # Read back independently of our probe: ffmpeg decodes every frame.
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "orbit.mp4"))[0] == 6
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"))
    meta = next(reader)
    assert meta["codec"] == "h264" and tuple(meta["size"]) == (32, 24)
    first = np.frombuffer(next(reader), np.uint8).reshape(24, 32, 3)
    reader.close()
    png = cv2.imread(str(tmp_path / "frames" / "00000.png"))[..., ::-1]
    # Lossy (4:2:0 chroma, crf 18) but the same picture: no colour shift, small mean error.
    assert np.abs(first.reshape(-1, 3).mean(0) - png.reshape(-1, 3).mean(0)).max() < 3
    assert np.abs(first.astype(float) - png).mean() < 10


def test_render_gif_with_an_odd_size(run_cli, tmp_path):
    path, _ = _scene(tmp_path)
    result = run_cli("render", path, "--orbit", 3, "-o", tmp_path / "frames", "--video", tmp_path / "orbit.gif",
                     "--width", 33, "--height", 21, "--fps", 10, "--json")
    assert result.code == 0, result.err
    video = json.loads(result.out)["video"]
    assert (video["codec"], video["width"], video["height"]) == ("gif", 33, 21)
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "orbit.gif"))[0] == 3


def test_render_orbit_without_cameras(run_cli, tmp_path):
    path, _ = _scene(tmp_path)
    result = run_cli("render", path, "--orbit", 2, "-o", tmp_path / "frames", "--quiet")
    assert result.code == 0, result.err
    image = cv2.imread(str(tmp_path / "frames" / "00000.png"))
    assert image.shape == (512, 512, 3) and image.mean() > 1


def test_render_bad_inputs_leave_nothing(run_cli, tmp_path):
    path, _ = _scene(tmp_path)
    out = tmp_path / "out"
    expect_input_error(run_cli("render", path, "-o", out), "give exactly one of --poses CAMERAS or --orbit N")
    expect_input_error(run_cli("render", path, "-o", out, "--orbit", 3, "--background", "red"), "--background 'red'")
    expect_input_error(run_cli("render", path, "-o", out, "--orbit", 0), "--orbit 0")
    expect_input_error(run_cli("render", path, "-o", out, "--orbit", 3, "--width", 0), "--width 0")
    expect_input_error(run_cli("render", path, "-o", out, "--orbit", 3, "--video", tmp_path / "a.avi"), "a.avi", "must end in .mp4")
    expect_input_error(run_cli("render", path, "-o", out, "--poses", tmp_path / "missing.json"), "missing.json: no such file")
    (tmp_path / "bad.ply").write_text("not a ply")
    expect_input_error(run_cli("render", tmp_path / "bad.ply", "-o", out, "--orbit", 2), "not a PLY file")
    # was "vv.mp4: is a folder where lumos3d writes a file", of the folder this run had just made
    expect_input_error(run_cli("render", path, "-o", tmp_path / "vv.mp4", "--orbit", 2, "--video", tmp_path / "vv.mp4"),
                       "vv.mp4: is the frames' folder -o as well; give the video another path")
    assert not out.exists() and not (tmp_path / "vv.mp4").exists()


def test_camera_files_with_sizes_of_their_own(run_cli, tmp_path):
    """A camera larger than the renderer's side limit is refused by name (it asked for 112 GiB);
    with one side given each camera keeps its own aspect ratio (a portrait view was stretched to
    the first camera's)."""
    path, gaussians = _scene(tmp_path)
    cameras = orbit_from_gaussians(gaussians, 2, 48, 32)
    huge = cameras.rescaled_to([(48, 32), (100000, 100000)])
    write_transforms_json(tmp_path / "huge.json", huge)
    expect_input_error(run_cli("render", path, "--poses", tmp_path / "huge.json", "-o", tmp_path / "a"),
                       "--poses", "huge.json: frames larger than 16384 pixels a side: 1 (100000x100000)",
                       "give a smaller width or height")
    write_transforms_json(tmp_path / "strip.json", cameras.rescaled_to([(48, 32), (16, 4000)]))
    expect_input_error(run_cli("render", path, "--poses", tmp_path / "strip.json", "-o", tmp_path / "a", "--width", 96),
                       "--width 96: makes 96x24000 frames of a 16x4000 camera, beyond 16384 pixels a side")
    small = run_cli("render", path, "--poses", tmp_path / "huge.json", "-o", tmp_path / "b", "--width", 50)
    assert small.code == 0, small.err
    write_transforms_json(tmp_path / "mixed.json", cameras.rescaled_to([(48, 32), (16, 32)]))
    result = run_cli("render", path, "--poses", tmp_path / "mixed.json", "-o", tmp_path / "c", "--width", 96, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["sizes"] == [[96, 64], [96, 192]]  # every size, not the first alone
    sizes = [cv2.imread(str(tmp_path / "c" / name)).shape[1::-1] for name in ("00000.png", "00001.png")]
    assert sizes == [(96, 64), (96, 192)]


def test_an_orbit_ignores_a_file_beside_the_scene_that_holds_no_cameras(run_cli, tmp_path):
    path, _ = _scene(tmp_path)
    (path.parent / "cameras.json").write_text('{"cameras": []}')
    result = run_cli("render", path, "--orbit", 2, "-o", tmp_path / "frames", "--width", 64, "--json")
    assert result.code == 0, result.err
    assert "cameras.json" in result.err and "passed over for the orbit" in " ".join(result.err.split())
    assert json.loads(result.out)["cameras"] == "orbit around the scene bounds"


def test_an_orbit_passes_over_a_broken_camera_file_for_the_next_one(run_cli, tmp_path):
    """A broken transforms.json beside the scene made the orbit go round the scene's bounds,
    although a valid cameras.json lay beside it too."""
    path, gaussians = _scene(tmp_path)
    write_transforms_json(path.parent / "cameras.json", orbit_from_gaussians(gaussians, 3, 48, 32))
    (path.parent / "transforms.json").write_text('{"frames": {"not": "a list"}}')
    result = run_cli("render", path, "--orbit", 2, "-o", tmp_path / "frames", "--width", 64, "--json")
    assert result.code == 0, result.err
    assert "transforms.json" in result.err and "passed over for the orbit" in " ".join(result.err.split())
    assert json.loads(result.out)["cameras"] == f"orbit around the cameras in {path.parent / 'cameras.json'}"
    (path.parent / "cameras.json").write_text("{")  # none readable: said once, after the files passed over
    result = run_cli("render", path, "--orbit", 2, "-o", tmp_path / "frames", "--width", 64, "--json")
    assert result.code == 0, result.err
    assert "no camera file beside it can be read; orbiting around the scene's bounds instead" in " ".join(result.err.split())


def test_a_camera_folder_that_cannot_be_read_is_passed_over_not_an_internal_error(tmp_path, monkeypatch):
    """Looking at every candidate met a colmap/ without read permission after a good sparse/0:
    `render --poses S` and `--orbit` ended in an internal PermissionError (as a user, not root)."""
    from lumos3d_cli.io import camera_files

    scene = tmp_path / "S"
    (scene / "colmap").mkdir(parents=True)
    write_transforms_json(scene / "transforms.json", orbit_from_gaussians(random_scene(20, 0), 2, 48, 32))
    real = camera_files.find_camera_source

    def unreadable(candidate):
        if candidate.name == "colmap":
            raise PermissionError(13, "Permission denied", str(candidate))
        return real(candidate)

    monkeypatch.setattr(camera_files, "find_camera_source", unreadable)
    assert list(camera_files.camera_sources(scene)) == [scene / "transforms.json"]


def test_cameras_with_a_field_of_view_no_lens_has_are_warned_of(run_cli, tmp_path):
    """A focal length of 1e30 px rendered black frames, exit 0, without a word."""
    path, gaussians = _scene(tmp_path)
    cameras = orbit_from_gaussians(gaussians, 2, 48, 32)
    cameras.intrinsics[0, 0, 0] = cameras.intrinsics[0, 1, 1] = 1e30
    write_transforms_json(tmp_path / "cameras.json", cameras)
    result = run_cli("render", path, "--poses", tmp_path / "cameras.json", "-o", tmp_path / "views")
    assert result.code == 0, result.err
    assert "1 camera(s) with a field of view no lens has" in " ".join(result.err.split())


def test_an_orbit_around_one_gaussian_sees_it(run_cli, tmp_path):
    """The orbit's radius came from the spread of the centres alone: 1e-6 around one Gaussian."""
    one = random_scene(1, 0, degree=0, dtype=torch.float32)
    one.means.zero_()
    one.scales.fill_(0.05)
    one.opacities.fill_(0.9)
    write_ply(tmp_path / "one.ply", one)
    result = run_cli("render", tmp_path / "one.ply", "--orbit", 2, "-o", tmp_path / "frames", "--width", 64)
    assert result.code == 0, result.err
    assert cv2.imread(str(tmp_path / "frames" / "00000.png")).max() > 0


def test_options_are_checked_before_the_scene_is_read_and_fast_gifs_warned_of(run_cli, tmp_path):
    (tmp_path / "broken.ply").write_text("not a ply")
    # the option's error, not the scene's: it is named before the (maybe large) scene is read
    expect_input_error(run_cli("render", tmp_path / "broken.ply", "--orbit", 2, "-o", tmp_path / "a", "--width", 0), "--width 0")
    (tmp_path / "cameras.json").write_text("{}")
    expect_input_error(run_cli("render", tmp_path / "broken.ply", "--poses", tmp_path / "cameras.json", "-o", tmp_path / "a"),
                       "cameras.json")
    path, _ = _scene(tmp_path)
    result = run_cli("render", path, "--orbit", 2, "-o", tmp_path / "frames", "--video", tmp_path / "fast.gif", "--fps", 60,
                     "--width", 16)
    assert result.code == 0, result.err
    assert "--fps 60: a GIF holds frame times in hundredths of a second" in " ".join(result.err.split())


def _moved_by(cameras, shift):
    """The same cameras with the world moved by +shift [3]."""
    rotation = cameras.extrinsics[:, :, :3].double()
    translation = cameras.extrinsics[:, :, 3].double() - rotation @ shift
    return type(cameras)(torch.cat([rotation, translation[:, :, None]], 2), cameras.intrinsics.double(), cameras.sizes,
                         cameras.names)


def test_far_poses_render_a_restores_centred_scene_where_it_lies(run_cli, tmp_path):
    """`restore` centres a scene whose poses lie far from their origin (georeferenced) and records
    where (summary.json geometry.poses_origin): `render` with the poses in their own frame moves
    them by that origin onto the scene, and renders what the restore's own cameras.json shows."""
    path, gaussians = _scene(tmp_path)
    cameras = orbit_from_gaussians(gaussians, 3, 48, 32)
    origin = [4.1e6, -2.5e5, 3.3e6]
    write_transforms_json(tmp_path / "near.json", cameras)
    write_transforms_json(tmp_path / "far.json", _moved_by(cameras, torch.tensor(origin, dtype=torch.float64)))
    summary = {"scene": str(path), "geometry": {"source": "poses", "poses_origin": origin}}
    (path.parent / "summary.json").write_text(json.dumps(summary))
    for name in ("near", "far"):
        result = run_cli("render", path, "--poses", tmp_path / f"{name}.json", "-o", tmp_path / name)
        assert result.code == 0, result.err
    for frame in listing(tmp_path / "near"):
        near, far = (cv2.imread(str(tmp_path / name / frame)).astype(float) for name in ("near", "far"))
        assert near.std() > 5 and np.abs(near - far).max() <= 1
    # a summary of another scene beside it says nothing about this one: the far cameras see nothing there
    (path.parent / "summary.json").write_text(json.dumps(summary | {"scene": "other.ply"}))
    result = run_cli("render", path, "--poses", tmp_path / "far.json", "-o", tmp_path / "unrelated")
    assert result.code == 0, result.err
    assert cv2.imread(str(tmp_path / "unrelated" / "00000.png")).max() == 0


def test_a_scene_and_cameras_far_from_the_origin_are_rendered_centred():
    """A scene given with its cameras millions of units out: both are moved to the cameras' centre
    in float64 before the float32 renderer sees them, so they render as they do near the origin."""
    from lumos3d_cli.pipeline.render_job import in_rendering_frame

    gaussians = random_scene(400, 0, degree=1, dtype=torch.float64, spread=0.4)
    cameras = orbit_from_gaussians(gaussians, 2, 48, 32)
    shift = torch.tensor([5e6, 5e6, 1e5], dtype=torch.float64)
    far_scene = replace(gaussians, means=gaussians.means + shift)
    moved_scene, moved_cameras = in_rendering_frame(Path("nowhere/scene.ply"), far_scene, _moved_by(cameras, shift))
    expected = render(gaussians, cameras.to(dtype=torch.float32)).images
    got = render(moved_scene, moved_cameras.to(dtype=torch.float32)).images
    assert expected.std() > 0.02 and (expected - got).abs().max() < 1e-3


def _panning(cameras, index, turns_degrees):
    """Cameras at camera `index`'s centre, turned about its y axis by each angle (a pan)."""
    rotation, centre = cameras.extrinsics[index, :, :3].double(), cameras.centers()[index].double()

    def about_y(angle):
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=torch.float64)

    turned = [about_y(angle) @ rotation for angle in turns_degrees]
    extrinsics = torch.stack([torch.cat([r, (-r @ centre)[:, None]], 1) for r in turned])
    return type(cameras)(extrinsics, cameras.intrinsics[[index] * len(turned)].double(),
                         [cameras.sizes[index]] * len(turned))


def test_cameras_already_in_a_centred_scenes_frame_are_never_moved_by_its_origin(run_cli, tmp_path):
    """A restore that centred far poses records their origin; cameras in the scene's own frame (a
    pan from one centre: its spread is rounding, 1e-15) were taken for far poses and moved by it, so
    `render` refused them as behind the scene. Where the origin brings the cameras nearer the
    scene's Gaussians they are moved; else not. And an orbit around far cameras beside the scene
    (a dataset's sparse/0) is made in the scene's frame."""
    path, gaussians = _scene(tmp_path)
    cameras = orbit_from_gaussians(gaussians, 3, 48, 32)
    origin = torch.tensor([4.1e6, -2.5e5, 3.3e6], dtype=torch.float64)
    (path.parent / "summary.json").write_text(json.dumps({"scene": str(path), "geometry": {"poses_origin": origin.tolist()}}))
    pan = _panning(cameras, 1, [-4, 0, 4])
    write_transforms_json(tmp_path / "pan.json", pan)
    result = run_cli("render", path, "--poses", tmp_path / "pan.json", "-o", tmp_path / "pan")
    assert result.code == 0, result.err
    middle = cv2.imread(str(tmp_path / "pan" / "00001.png")).astype(float)
    expected = render(gaussians, cameras[1]).images[0].permute(1, 2, 0).numpy()[..., ::-1] * 255
    assert middle.std() > 5 and np.abs(middle - expected).max() <= 1.5
    # the same pan in the poses' own frame is moved onto the scene
    write_transforms_json(tmp_path / "far-pan.json", _moved_by(pan, origin))
    result = run_cli("render", path, "--poses", tmp_path / "far-pan.json", "-o", tmp_path / "far-pan")
    assert result.code == 0, result.err
    assert np.abs(cv2.imread(str(tmp_path / "far-pan" / "00001.png")).astype(float) - middle).max() <= 1
    # an orbit around the dataset's far cameras beside the scene
    write_transforms_json(path.parent / "transforms.json", _moved_by(cameras, origin))
    result = run_cli("render", path, "--orbit", 2, "-o", tmp_path / "orbit", "--json")
    assert result.code == 0, result.err
    frames = [cv2.imread(str(tmp_path / "orbit" / name)) for name in ("00000.png", "00001.png")]
    assert all(frame.std() > 5 for frame in frames)
