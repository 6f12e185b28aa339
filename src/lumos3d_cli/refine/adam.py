"""Adam for refinement's Gaussians on PyTorch's fused kernel, without `torch.optim`'s step.

`torch.optim.Optimizer.step` imports torch._dynamo on its first call (with sympy: 1.1-1.5 s of one
core, 1.9 s while the network pass and structure-from-motion hold both cores of a `fast`
restore). Refinement needs none of what that buys (compilation, hooks, differentiable steps): this
keeps the state as torch.optim.Adam keeps it (`param_groups` of one tensor with its "lr",
`state[tensor]` with "step", "exp_avg" and "exp_avg_sq"; densification swaps
tensors and moments in place: `refine.densification`) and updates each tensor with
`torch._fused_adam_`, the kernel `torch.optim.Adam(fused=True)` calls, on the CPU and CUDA alike.
Tested against `torch.optim.Adam` (tests/refine/test_adam.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

FUSED_DEVICES = ("cpu", "cuda")  # where torch._fused_adam_ runs


class FusedAdam:
    """Adam (betas 0.9, 0.999; no weight decay) over `groups`, each (tensor, learning rate): one
    parameter group per tensor, so that each keeps its own rate. The tensors must be on a
    FUSED_DEVICES device."""

    def __init__(self, groups: Sequence[tuple[torch.Tensor, float]], eps: float = 1e-8,
                 betas: tuple[float, float] = (0.9, 0.999)):
        for tensor, _ in groups:
            if tensor.device.type not in FUSED_DEVICES:
                raise ValueError(f"the fused Adam runs on {', '.join(FUSED_DEVICES)}, not {tensor.device.type}")
        self.param_groups = [{"params": [tensor], "lr": lr} for tensor, lr in groups]
        self.state: dict[torch.Tensor, dict[str, torch.Tensor]] = {}
        self.eps, self.betas = eps, betas

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Drop every tensor's gradient (`set_to_none` is accepted for torch.optim's signature)."""
        for group in self.param_groups:
            for tensor in group["params"]:
                tensor.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every tensor that has a gradient; the first creates its moments."""
        for group in self.param_groups:
            for tensor in group["params"]:
                if tensor.grad is None:
                    continue
                state = self.state.get(tensor)
                if state is None:
                    state = self.state[tensor] = {
                        # the step count as a float32 scalar tensor, as torch.optim keeps it
                        "step": torch.zeros((), dtype=torch.float32, device=tensor.device),
                        "exp_avg": torch.zeros_like(tensor, memory_format=torch.preserve_format),
                        "exp_avg_sq": torch.zeros_like(tensor, memory_format=torch.preserve_format),
                    }
                state["step"] += 1
                torch._fused_adam_(
                    [tensor], [tensor.grad], [state["exp_avg"]], [state["exp_avg_sq"]], [], [state["step"]],
                    amsgrad=False, lr=group["lr"], beta1=self.betas[0], beta2=self.betas[1], weight_decay=0.0,
                    eps=self.eps, maximize=False,
                )
