"""Training on the GPU (issue 37): a few teacher steps with `device: cuda` run with finite losses,
render through gsplat, and leave a checkpoint that loads on the CPU and predicts what the GPU
model predicted. Runs where CUDA and gsplat exist (`make test-cuda`); skips elsewhere."""

import importlib.util

import pytest
import torch

from lumos3d_cli.model.loading import load_model
from lumos3d_cli.train.config import load_config
from lumos3d_cli.train.distributed import setup_distributed
from lumos3d_cli.train.trainer import Trainer

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"),
    pytest.mark.skipif(importlib.util.find_spec("gsplat") is None, reason="needs gsplat (docs/performance.md, GPU)"),
]


def test_teacher_steps_on_cuda_and_the_checkpoint_on_the_cpu(tiny_config):
    config = load_config(tiny_config(name="cuda", optim__steps=3, device="cuda"), [])
    trainer = Trainer(config, setup_distributed("cuda"))
    assert trainer.device.type == "cuda"
    result = trainer.run()
    assert result.steps_done == 3 and all(torch.isfinite(torch.tensor(list(r.terms.values()))).all() for r in result.history)
    images = torch.rand(1, 2, 3, 42, 56)
    with torch.no_grad():
        gpu = trainer.model.eval().predict(images.cuda()).depth.cpu()
        cpu = load_model(result.final_checkpoint, device="cpu").predict(images).depth
    # float32 on two devices: the same weights give depth within 1e-3 relative
    torch.testing.assert_close(gpu, cpu, rtol=1e-3, atol=1e-4)
