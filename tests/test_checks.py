"""require_finite (checks.py): its fast sum in the values' own precision must neither miss a NaN
or Inf nor raise on finite values whose sum overflows."""

import numpy as np
import pytest
import torch

from lumos3d_cli.checks import count_non_finite, require_finite
from lumos3d_cli.errors import NonFiniteError


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.bfloat16, torch.float16])
def test_finite_values_whose_sum_overflows_pass(dtype):
    big = torch.full((1000,), torch.finfo(dtype).max / 2, dtype=dtype)
    require_finite("big", big)
    require_finite("big", big.float().numpy() if dtype in (torch.bfloat16, torch.float16) else big.numpy())


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.bfloat16])
def test_one_non_finite_value_is_named_and_counted(bad, dtype):
    values = torch.rand(50, 4, 3).to(dtype)
    values[17, 2, 1] = bad
    with pytest.raises(NonFiniteError, match=r"scene.sh: 1 of 600 values are NaN or Inf"):
        require_finite("scene.sh", values)
    with pytest.raises(NonFiniteError, match="1 of 600"):
        require_finite("scene.sh", values.float().numpy())
    assert count_non_finite(values) == 1


def test_non_contiguous_and_integer_values():
    values = torch.rand(10, 3, 4).transpose(1, 2)
    require_finite("view", values)
    values[3, 1, 2] = float("nan")
    with pytest.raises(NonFiniteError):
        require_finite("view", values)
    require_finite("integers", np.arange(10))
