"""Process-group set-up for `torchrun` (DistributedDataParallel): gloo on CPU, nccl on CUDA."""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from lumos3d_cli.errors import InputError, RunError


@dataclass(frozen=True)
class DistributedContext:
    rank: int
    world_size: int
    local_rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def resolve_device(preference: str, local_rank: int = 0) -> torch.device:
    if preference == "cuda" or (preference == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise InputError("device cuda: CUDA is not available on this machine; train with device=cpu (or auto)")
        return torch.device("cuda", local_rank)
    return torch.device("cpu")


def setup_distributed(device_preference: str) -> DistributedContext:
    """Read torchrun's environment (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, MASTER_PORT)."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    device = resolve_device(device_preference, local_rank)
    if world_size > 1 and not dist.is_initialized():
        backend = "nccl" if device.type == "cuda" else "gloo"
        if device.type == "cuda":
            torch.cuda.set_device(device)
        dist.init_process_group(backend=backend)
    return DistributedContext(rank, world_size, local_rank, device)


def shutdown_distributed() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()


def all_reduce_mean(value: torch.Tensor, context: DistributedContext) -> torch.Tensor:
    """Mean of a tensor over ranks (the tensor itself on one process)."""
    if not context.enabled:
        return value
    reduced = value.detach().clone()
    dist.all_reduce(reduced, op=dist.ReduceOp.SUM)
    return reduced / context.world_size


def average_gradients(parameters: list[torch.nn.Parameter], context: DistributedContext,
                      bucket_elements: int = 1 << 24) -> None:
    """Average the gradients of `parameters` over ranks in place, for a step whose loss never went
    through the DistributedDataParallel wrapper's forward (its reducer then shares nothing, and each
    rank would train a model of its own). A parameter with a gradient on some rank gets the mean
    over all ranks (a rank without one counts zeros); one with a gradient on no rank keeps none, so
    the optimizer leaves it alone (a zero gradient would let AdamW's weight decay shrink it on
    several processes but not on one). Reduced in buckets of at most `bucket_elements` values, so
    the copy costs at most one bucket beside the gradients."""
    if not context.enabled:
        return
    has_gradient = torch.tensor([parameter.grad is not None for parameter in parameters], dtype=torch.float32,
                                device=context.device)
    dist.all_reduce(has_gradient, op=dist.ReduceOp.MAX)
    used = [parameter for parameter, flag in zip(parameters, has_gradient.tolist()) if flag > 0]
    for parameter in used:
        if parameter.grad is None:
            parameter.grad = torch.zeros_like(parameter)
    bucket: list[torch.Tensor] = []
    filled = 0
    for index, parameter in enumerate(used):
        bucket.append(parameter.grad)
        filled += parameter.grad.numel()
        if filled >= bucket_elements or index == len(used) - 1:
            _average_bucket(bucket, context)
            bucket, filled = [], 0


def _average_bucket(gradients: list[torch.Tensor], context: DistributedContext) -> None:
    flat = torch.cat([gradient.reshape(-1) for gradient in gradients])
    dist.all_reduce(flat, op=dist.ReduceOp.SUM)
    flat /= context.world_size
    offset = 0
    for gradient in gradients:
        gradient.copy_(flat[offset: offset + gradient.numel()].view_as(gradient))
        offset += gradient.numel()


def any_rank(flag: bool, context: DistributedContext) -> bool:
    """True when `flag` is true on any rank (so every rank takes the same branch)."""
    if not context.enabled:
        return flag
    value = torch.tensor([1.0 if flag else 0.0], device=context.device)
    dist.all_reduce(value, op=dist.ReduceOp.MAX)
    return bool(value.item() > 0)


def peer_stopped(error: BaseException, context: DistributedContext) -> RunError | None:
    """The RunError to report instead of `error` when it is a collective that failed because another
    process of the run ended (it stopped on bad data, or was killed): that process's own message
    says why, and "internal error ... report it" from the survivors said nothing true. None for
    anything else."""
    if not context.enabled or not isinstance(error, RuntimeError):
        return None
    text = str(error).lower()
    if not (isinstance(error, dist.DistError) or "gloo" in text or "nccl" in text):
        return None
    first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    return RunError(f"rank {context.rank}: another process of this distributed run stopped (its own message says why), "
                    f"so this one stops too; a --resume continues from the last checkpoint (here: {first_line})")
