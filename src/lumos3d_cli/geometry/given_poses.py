"""Cameras the user already has (`--poses PATH`), matched to the photos by file stem.

PATH is a transforms.json (nerfstudio / instant-ngp / LOM), a folder of LOM-style
transforms_{train,val,test}.json, a COLMAP model folder (text or binary), or a scene folder
holding one of those (sparse/0, colmap/, transforms.json). A pose of `photos/IMG_01.JPG` matches
the photo `img_01.png`: only the stem counts, in any case, since restored or converted photos
change suffix (and some tools the case).

Every photo needs a pose, and by default every pose needs a photo: a file with extra poses is
most likely the file of another capture, so it is an error (`allow_extra_poses=True` accepts a
file that covers a superset of the photos, e.g. the train/test split of a dataset).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError, listed
from lumos3d_cli.geometry.similarity import moved_to_origin
from lumos3d_cli.io.camera_files import read_cameras
from lumos3d_cli.io.cameras import Cameras

logger = logging.getLogger(__name__)

# Aspect ratios that differ by more than this mean the photos were cropped, not resized.
_ASPECT_TOLERANCE = 0.01
# Cameras whose mean centre lies further from the origin than this many times their spread are
# moved to it. float32, in which the Gaussians' positions and the renderer work, holds a coordinate
# to 6e-8 of its size: at 1,000 spreads out that is 6e-5 of the spread, finer than the photos' detail.
# Georeferenced poses (UTM, ECEF) lie 1e5-1e7 out for a scene metres across: 10 of buu's photos with
# their poses moved 5e6 out restored as streaks (3,775 Gaussians instead of 147,603), the depth
# sweep and the renderer rounding every position to half a unit.
FAR_FROM_ORIGIN = 1000.0


def read_given_poses(
    path: Path | str, names: Sequence[str], sizes: Sequence[tuple[int, int]], allow_extra_poses: bool = False,
    warn_on_distortion: bool = True,
) -> Cameras:
    """The cameras of the photos `names` (file names, one per photo) of `sizes` (width, height)
    from PATH, in the photos' order, with intrinsics rescaled to the photos' sizes.

    InputError naming the photos without a pose, the poses without a photo (unless
    `allow_extra_poses`), two different poses of one stem (the same pose listed twice is fine), or
    a photo whose aspect ratio differs from its pose's image (a cropped photo: its principal point
    is unknown). Lens distortion is warned of unless `warn_on_distortion` is False (a check of a
    file read again later).
    """
    path = Path(path)
    if len(names) != len(sizes):
        raise InputError(f"{len(names)} photo names for {len(sizes)} photo sizes")
    if not path.exists():
        raise InputError(f"{path}: no such file or folder", parameter="poses")
    # lens distortion is ignored (the photos are taken as pinhole ones), with one warning when
    # `warn_on_distortion`: a distorted photo's pixels sit pixels away from where its pinhole
    # camera puts them (buu's given poses reproject its points 3-4 px off, SfM's own 0.6 px)
    given = read_cameras(path, warn_on_distortion)
    # matched by stem in any case: IMG_01.JPG's pose is img_01.png's (cameras and converters change both)
    stems = [Path(name).stem.casefold() for name in given.names]
    row_of_stem: dict[str, int] = {}
    conflicting = []
    for row, stem in enumerate(stems):
        if stem not in row_of_stem:
            row_of_stem[stem] = row
            continue
        # LOM lists a frame in two split files; the same pose twice is harmless, two poses are not.
        first = row_of_stem[stem]
        if not (torch.allclose(given.extrinsics[first], given.extrinsics[row], atol=1e-9)
                and torch.allclose(given.intrinsics[first], given.intrinsics[row], atol=1e-9)):
            conflicting.append(given.names[row])
    if conflicting:
        raise InputError(f"{path}: differing poses for one photo ({listed(conflicting)}); keep one pose per photo",
                         parameter="poses")
    photo_stems = [Path(name).stem.casefold() for name in names]
    missing = [name for name, stem in zip(names, photo_stems) if stem not in row_of_stem]
    if missing:
        raise InputError(f"{path}: no pose for {len(missing)} of {len(names)} photos ({listed(missing)}); "
                         "poses are matched to photos by file name without suffix", parameter="poses")
    extra = [given.names[row] for stem, row in row_of_stem.items() if stem not in set(photo_stems)]
    if extra and not allow_extra_poses:
        raise InputError(f"{path}: {len(extra)} poses have no photo ({listed(extra)}); "
                         "pass the photos of every pose, or a camera file of these photos only", parameter="poses")
    rows = [row_of_stem[stem] for stem in photo_stems]
    chosen = given[rows]
    intrinsics = chosen.intrinsics.double().clone()
    for view, ((width, height), (file_width, file_height)) in enumerate(zip(sizes, chosen.sizes)):
        if (width, height) == (file_width, file_height):
            continue
        if abs((width / height) / (file_width / file_height) - 1) > _ASPECT_TOLERANCE:
            raise InputError(f"{path}: photo {names[view]} is {width}x{height} but its pose is for "
                             f"{file_width}x{file_height} (another aspect ratio); pass uncropped photos", parameter="poses")
        intrinsics[view, 0] *= width / file_width
        intrinsics[view, 1] *= height / file_height
    cameras = Cameras(chosen.extrinsics.double(), intrinsics, list(sizes), list(names))
    cameras.require_valid(str(path), remedy="correct the camera file")
    if extra:
        logger.info("poses %s: %d poses without a photo are not used", path, len(extra))
    return cameras


def centred_if_far(cameras: Cameras) -> tuple[Cameras, torch.Tensor | None]:
    """(the cameras, None); or, when their mean centre lies more than FAR_FROM_ORIGIN spreads (the
    RMS distance of the centres from their mean; one unit where they share one centre) from the
    origin, (the same cameras in the frame moved to that centre, the centre [3] float64): a scene
    built from them lies around the origin, and adding the centre to its positions puts it back
    into the cameras' frame. Exact: the move is made in float64."""
    centres = cameras.centers().double()
    middle = centres.mean(dim=0)
    spread = float((centres - middle).square().sum(dim=1).mean().sqrt())
    if spread <= 1e-9 * float(middle.norm()):  # one centre, up to the rounding of -R^T t (a pan, a rotation)
        spread = 0.0
    if float(middle.norm()) <= FAR_FROM_ORIGIN * (spread if spread > 0 else 1.0):
        return cameras, None
    return moved_to_origin(cameras, middle), middle
