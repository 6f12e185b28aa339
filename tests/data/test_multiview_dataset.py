import cv2
import numpy as np
import pytest
import torch

from lumos3d_cli.data.augment import centred_box, crop_and_resize, crop_box, mirror
from lumos3d_cli.data.multiview_dataset import MultiViewDataset, project_sparse_depth
from lumos3d_cli.data.scene_records import scan_scene_folders
from lumos3d_cli.data.view_sampling import sample_views
from lumos3d_cli.io.cameras import Cameras


@pytest.fixture(scope="module")
def records(shared_data):
    return scan_scene_folders(shared_data / "scenes")


def test_scan_finds_every_scene_with_its_poses(records):
    by_name = {r.name: r for r in records}
    assert len(records) == 27
    kitchen = by_name["kitchen"]
    assert len(kitchen.image_paths) == 25 and len(kitchen.posed) == 17
    assert kitchen.points_xyz.shape == (763, 3) and set(kitchen.observed) <= set(kitchen.posed)
    assert by_name["cake"].cameras is None and by_name["cake"].posed == []
    for record in records:
        if record.cameras is not None:
            assert [record.image_paths[v].name for v in record.posed] == [n.split("/")[-1] for n in record.cameras.names]


def test_view_sampling_prefers_overlapping_views(records):
    kitchen = next(r for r in records if r.name == "kitchen")
    rng = np.random.default_rng(0)
    for _ in range(20):
        views = sample_views(kitchen, 4, rng, require_poses=True)
        assert len(set(views)) == 4 and all(v in kitchen.posed for v in views)
        anchor = kitchen.observed[views[0]]
        shared = [np.intersect1d(anchor, kitchen.observed.get(v, np.empty(0))).size for v in views[1:]]
        assert min(shared) > 0  # every partner shares sparse points with the anchor


def test_samples_are_deterministic_and_consistent(records):
    dataset = MultiViewDataset(records, 3, (112, 84), require_poses=True, seed=5)
    a, b = dataset[7], dataset[7]
    assert torch.equal(a["images"], b["images"]) and torch.equal(a["extrinsics"], b["extrinsics"])
    dataset.set_epoch(1)
    assert not torch.equal(dataset[7]["images"], a["images"]) or dataset[7]["views"].tolist() != a["views"].tolist()
    assert a["images"].shape == (3, 3, 84, 112) and a["images"].min() >= 0 and a["images"].max() <= 1
    torch.testing.assert_close(a["extrinsics"][0], torch.eye(4)[:3], atol=1e-5, rtol=0)
    rotation = a["extrinsics"][:, :, :3]
    torch.testing.assert_close(torch.linalg.det(rotation), torch.ones(3), atol=1e-5, rtol=0)
    assert bool(a["has_poses"])


def test_sparse_depth_lands_on_the_colmap_observations(records, shared_data):
    """Without crop and mirror, each projected sparse point must fall on the 2D keypoint COLMAP
    measured for it, scaled to the network size."""
    kitchen = next(r for r in records if r.name == "kitchen")
    dataset = MultiViewDataset([kitchen], 2, (256, 171), crop_scale=(1.0, 1.0), flip=False, require_poses=True, seed=0)
    sample = dataset[0]
    view = int(sample["views"][0])
    row = kitchen.camera_of(view)
    camera = kitchen.cameras[[row]]
    lines = [l for l in (shared_data / "scenes/kitchen/sparse/0/images.txt").read_text().splitlines() if not l.startswith("#")]
    for header, observations in zip(lines[0::2], lines[1::2]):
        if header.split()[9] == kitchen.image_paths[view].name:
            keypoints = np.asarray(observations.split(), dtype=np.float64).reshape(-1, 3)
            break
    keypoints = keypoints[keypoints[:, 2] >= 0]
    scale_x, scale_y = 256 / camera.sizes[0][0], 171 / camera.sizes[0][1]
    hits = 0
    for x, y, _ in keypoints:
        column, line = int(x * scale_x), int(y * scale_y)
        if 0 <= column < 256 and 0 <= line < 171:
            window = sample["sparse_depth"][0, max(0, line - 1) : line + 2, max(0, column - 1) : column + 2]
            hits += bool((window > 0).any())
    assert hits / len(keypoints) > 0.8
    assert sample["sparse_depth"][0][sample["sparse_depth"][0] > 0].median().item() == pytest.approx(1.0, rel=0.3)


def test_crop_keeps_projections_consistent():
    rng = np.random.default_rng(0)
    images = torch.rand(2, 3, 60, 80)
    intrinsics = torch.tensor([[[50.0, 0, 40], [0, 50, 30], [0, 0, 1]]]).repeat(2, 1, 1)
    box = crop_box(80, 60, 32, 24, 0.5, rng)
    _, cropped = crop_and_resize(images, intrinsics, box, 32, 24)
    point = torch.tensor([0.1, -0.05, 1.0])
    before = intrinsics[0] @ point
    after = cropped[0] @ point
    x0, y0, width, height = box
    assert (after[0] / after[2]).item() == pytest.approx(((before[0] / before[2]).item() - x0) * 32 / width, rel=1e-5)
    assert (after[1] / after[2]).item() == pytest.approx(((before[1] / before[2]).item() - y0) * 24 / height, rel=1e-5)


def test_mirror_keeps_geometry_valid():
    rotation = torch.linalg.qr(torch.randn(3, 3, dtype=torch.float64))[0]
    rotation = rotation * torch.sign(torch.linalg.det(rotation))
    extrinsics = torch.cat([rotation, torch.randn(3, 1, dtype=torch.float64)], 1)[None]
    intrinsics = torch.tensor([[[50.0, 0, 30], [0, 50, 20], [0, 0, 1]]], dtype=torch.float64)
    points = np.array([[0.3, -0.2, 4.0]])
    images = torch.rand(1, 3, 40, 64)
    flipped, k, e, p = mirror(images, intrinsics, extrinsics, points)
    assert torch.linalg.det(e[0, :, :3]) == pytest.approx(1.0)
    original = Cameras(extrinsics, intrinsics, [(64, 40)]).project(torch.from_numpy(points))[0][0, 0]
    mirrored = Cameras(e, k, [(64, 40)]).project(torch.from_numpy(p))[0][0, 0]
    assert mirrored[0].item() == pytest.approx(64 - original[0].item())
    assert mirrored[1].item() == pytest.approx(original[1].item())
    assert torch.equal(flipped[0, :, :, 0], images[0, :, :, -1])


def test_project_sparse_depth_keeps_the_nearest():
    extrinsics = torch.eye(4)[:3]
    intrinsics = torch.tensor([[10.0, 0, 5], [0, 10, 5], [0, 0, 1]])
    points = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    depth = project_sparse_depth(points, extrinsics, intrinsics, 10, 10)
    assert depth[5, 5] == 1.0 and (depth > 0).sum() == 1


def test_project_sparse_depth_is_a_z_buffer_at_any_density_and_thread_count():
    """Thousands of points on few pixels: every pixel holds its nearest point's depth, checked
    against numpy's minimum.at, with one thread and with two (an indexed write of repeated pixels
    kept an arbitrary point from about 4,000 points on two threads)."""
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.uniform(-1, 1, (20000, 2)), rng.uniform(1, 5, (20000, 1))], axis=1)
    extrinsics = torch.eye(4, dtype=torch.float64)[:3]
    intrinsics = torch.tensor([[20.0, 0, 16], [0, 20, 12], [0, 0, 1]], dtype=torch.float64)
    pixels = (points / points[:, 2:]) @ intrinsics.numpy().T
    columns, rows = np.floor(pixels[:, 0]).astype(int), np.floor(pixels[:, 1]).astype(int)
    inside = (columns >= 0) & (columns < 32) & (rows >= 0) & (rows < 24)
    expected = np.full((24, 32), np.inf, np.float32)
    np.minimum.at(expected, (rows[inside], columns[inside]), points[inside, 2].astype(np.float32))
    expected[np.isinf(expected)] = 0
    threads = torch.get_num_threads()
    try:
        for count in (1, 2):
            torch.set_num_threads(count)
            depth = project_sparse_depth(points, extrinsics, intrinsics, 32, 24)
            assert depth.dtype == torch.float32 and np.array_equal(depth.numpy(), expected), count
    finally:
        torch.set_num_threads(threads)


def test_the_image_cache_stays_within_its_budget_and_changes_no_sample(records):
    kitchen = next(r for r in records if r.name == "kitchen")
    unbounded = MultiViewDataset([kitchen], 3, (112, 84), require_poses=True, seed=5, samples_per_scene=6)
    one_photo = 600 * 450 * 3 * 2  # kitchen's photos are smaller: about two fit
    bounded = MultiViewDataset([kitchen], 3, (112, 84), require_poses=True, seed=5, samples_per_scene=6, cache_bytes=one_photo)
    for index in range(6):
        assert torch.equal(unbounded[index]["images"], bounded[index]["images"])
        assert 0 < bounded._cached_bytes <= one_photo and len(bounded._cache) >= 1
        assert bounded._cached_bytes == sum(image.nbytes for image in bounded._cache.values())
    assert len(unbounded._cache) > len(bounded._cache)


def test_views_of_another_aspect_are_cropped_never_stretched(tmp_path):
    """A portrait photo among landscape ones (british_museum holds one): its view is its centre at
    the first view's aspect, never stretched to the first view's size (a disc came out 1.8x wide),
    and posed views' intrinsics follow the crop (fx / fy stays the camera's own)."""
    images = tmp_path / "scene" / "images"
    images.mkdir(parents=True)
    for name, (width, height) in {"0.png": (160, 120), "1.png": (160, 120), "2.png": (120, 160)}.items():
        picture = np.full((height, width, 3), 255, np.uint8)
        cv2.circle(picture, (width // 2, height // 2), 10, (0, 0, 0), -1)  # inside any crop of the sample
        cv2.imwrite(str(images / name), picture)
    record = scan_scene_folders(tmp_path)[0]
    dataset = MultiViewDataset([record], 3, (112, 84), crop_scale=(1.0, 1.0), flip=False, seed=0, samples_per_scene=6)
    for index in range(6):
        for view in dataset[index]["images"]:
            rows, columns = np.nonzero(view.mean(0).numpy() < 0.5)
            assert abs((np.ptp(columns) + 1) / (np.ptp(rows) + 1) - 1) < 0.2  # stretched: 1.8 or 0.56
    intrinsics = torch.tensor([[[100.0, 0, 80], [0, 100, 60], [0, 0, 1]], [[100.0, 0, 60], [0, 100, 80], [0, 0, 1]]])
    box = centred_box(120, 160, 160, 120)
    assert box == (0, 35, 120, 90)
    _, cropped = crop_and_resize(torch.zeros(1, 3, 160, 120), intrinsics[1:], box, 160, 120)
    torch.testing.assert_close(cropped[0, 0, 0] / cropped[0, 1, 1], torch.tensor(1.0))
    assert cropped[0, 0, 2].item() == pytest.approx(80) and cropped[0, 1, 2].item() == pytest.approx(60)
