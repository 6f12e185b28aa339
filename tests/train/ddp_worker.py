"""Run by torchrun in test_trainer: train a few steps, then save this rank's parameters."""

import sys
from pathlib import Path

import torch

from lumos3d_cli.train.config import load_config
from lumos3d_cli.train.distributed import setup_distributed, shutdown_distributed
from lumos3d_cli.train.trainer import Trainer

config_path, out = sys.argv[1], Path(sys.argv[2])
context = setup_distributed("cpu")
trainer = Trainer(load_config(config_path), context)
if context.rank == 0:
    torch.save({k: v.clone() for k, v in trainer.model.state_dict().items()}, out / "initial.pt")
trainer.run()
torch.save(trainer.model.state_dict(), out / f"rank{context.rank}.pt")
shutdown_distributed()
