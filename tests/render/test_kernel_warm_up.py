"""The kernel warm-up loads what a restore's renders use: after it, a budget render (weights)
and a refinement step (forward and backward) of a real-sized float32 scene add no new compiled
specialisation of any rasterizer kernel (a fresh process, so that no other test loaded them)."""

import subprocess
import sys

SCRIPT = """
import sys
sys.path.insert(0, "tests")
import torch
from factories import random_scene
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.render.kernel_warm_up import load_compiled_kernels
from lumos3d_cli.render.kernels import binning, projection, radix_sort, rasterize
from lumos3d_cli.render.contribution import rendered_weights
from lumos3d_cli.render.render import render

kernels = [projection.project_forward, projection.project_backward, binning._count_per_chunk,
           binning._fill_per_chunk, radix_sort._count_digits, radix_sort._scatter,
           rasterize.rasterize_forward, rasterize.rasterize_backward, rasterize.gather_entry_gradients]
assert all(not kernel.signatures for kernel in kernels)
load_compiled_kernels()
loaded = [list(kernel.signatures) for kernel in kernels]
assert all(loaded), [kernel.__name__ for kernel, signatures in zip(kernels, loaded) if not signatures]

# 100k Gaussians with the SH bands of a real scene.
scene = random_scene(100_000, 0, degree=3, dtype=torch.float32)
intrinsics = torch.tensor([[[120.0, 0.0, 80.0], [0.0, 120.0, 60.0], [0.0, 0.0, 1.0]]])
camera = Cameras(torch.eye(4)[:3][None], intrinsics, [(160, 120)])
rendered_weights(scene, camera)
parameters = [scene.means, scene.quats, scene.scales, scene.opacities, scene.sh]
for tensor in parameters:
    tensor.requires_grad_(True)
torch.autograd.grad(render(scene, camera).images.sum(), parameters)
after = [list(kernel.signatures) for kernel in kernels]
assert after == loaded, [kernel.__name__ for kernel, a, b in zip(kernels, after, loaded) if a != b]
print("ok")
"""


def test_the_warm_up_loads_every_specialisation_a_render_uses():
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "ok"
