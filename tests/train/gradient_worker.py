"""Run by torchrun in test_trainer: average_gradients over two gloo processes, then save what each
rank's parameters hold."""

import sys
from pathlib import Path

import torch

from lumos3d_cli.train.distributed import average_gradients, setup_distributed, shutdown_distributed

out = Path(sys.argv[1])
context = setup_distributed("cpu")
torch.manual_seed(0)
used, partly, unused = torch.nn.Linear(3, 1), torch.nn.Linear(3, 1), torch.nn.Linear(3, 1)
torch.manual_seed(1 + context.rank)  # each rank its own samples
loss = used(torch.randn(2, 3)).pow(2).mean()
if context.rank == 0:  # a module only rank 0's loss reaches
    loss = loss + partly(torch.randn(2, 3)).pow(2).mean()
loss.backward()
own = {name: p.grad.clone() for name, p in [("used", used.weight), ("partly", partly.weight)] if p.grad is not None}
average_gradients([*used.parameters(), *partly.parameters(), *unused.parameters()], context, bucket_elements=4)
torch.save({"own": own, "used": used.weight.grad, "partly": partly.weight.grad, "unused": unused.weight.grad},
           out / f"rank{context.rank}.pt")
shutdown_distributed()
