import subprocess
import sys

import lumos3d_cli
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import Lumos3DOutput, build_model


def test_the_network_api_is_re_exported_from_the_package():
    assert lumos3d_cli.build_model is build_model and lumos3d_cli.load_model is load_model
    assert lumos3d_cli.Lumos3DOutput is Lumos3DOutput
    assert {"build_model", "load_model", "save_checkpoint", "summarize_checkpoint"} <= set(dir(lumos3d_cli))


def test_importing_the_package_does_not_import_torch():
    code = "import sys, lumos3d_cli; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"


def test_restore_scene_takes_a_preset_name_and_refuses_photos_outside_the_unit_range(tmp_path):
    """`restore_scene(batch, model, "fast")` was an AttributeError; photos of 8-bit codes ran to a
    scene whose only warnings blamed the photos (SfM found nothing, a 0.06-degree field of view)."""
    import numpy as np
    import pytest

    from lumos3d_cli.errors import InputError
    from lumos3d_cli.io.image_write import write_image

    for name in ("1.png", "2.png"):
        write_image(tmp_path / name, np.random.default_rng(0).random((42, 56, 3)).astype(np.float32))
    batch = lumos3d_cli.load_images(tmp_path)
    batch.images.mul_(255)
    model = build_model("tiny", seed=0)
    with pytest.raises(InputError, match=r"photos: values from .* to .*; give sRGB in \[0, 1\] \(8-bit codes: divide by 255\)"):
        lumos3d_cli.restore_scene(batch, model, "fast")
    with pytest.raises(InputError, match="preset 3: give a preset's name or a RestorePreset"):
        lumos3d_cli.restore_scene(batch, model, 3)
