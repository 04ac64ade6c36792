"""Device and precision helpers."""

import pytest
import torch

from sin3dm_lite.device import autocast, bf16_is_fast
from sin3dm_lite.errors import Sin3DMInputError


def test_autocast_precisions():
    a, b = torch.randn(8, 8), torch.randn(8, 8)
    with autocast("cpu", "fp32"):
        assert (a @ b).dtype == torch.float32
    with autocast("cpu", "bf16"):
        assert (a @ b).dtype == torch.bfloat16
    with autocast("cpu", "auto"):
        assert (a @ b).dtype == (torch.bfloat16 if bf16_is_fast("cpu") else torch.float32)
    with pytest.raises(Sin3DMInputError, match="precision"):
        autocast("cpu", "fp8")
