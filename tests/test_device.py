"""Device and precision helpers."""

import pytest
import torch

from sin3dm_lite.app.device import autocast, bf16_is_fast
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


def test_auto_precision_picks_bf16_only_where_it_measures_faster(monkeypatch):
    """The CPU's flag alone does not make bf16 fast (a Xeon with AVX512-BF16 ran the autoencoder's MLPs 1.3-1.6x
    slower in bf16): where the flag is present the speed is measured once, and 'auto' follows the measurement; where
    it is absent nothing is timed (emulated bf16 is many times slower). The default preset's reason says which."""
    from sin3dm_lite.app import device
    from sin3dm_lite.auto import fit_default

    device.cpu_bf16_share.cache_clear()
    monkeypatch.setattr(device, "_cpu_has_bf16", lambda: False)
    assert device.cpu_bf16_share() is None and not device.bf16_is_fast("cpu")
    name, why = fit_default.choose_preset("cpu")
    assert name == "quick" and "without native bf16" in why
    device.cpu_bf16_share.cache_clear()
    monkeypatch.setattr(device, "_cpu_has_bf16", lambda: True)
    torch.manual_seed(3)
    share = device.cpu_bf16_share()  # timed here, whatever this CPU is
    drawn = torch.rand(3)
    torch.manual_seed(3)
    assert torch.equal(torch.rand(3), drawn)  # a seeded fit draws the same numbers whether or when it ran
    assert share > 0 and device.cpu_bf16_share() == share  # once a process
    assert device.bf16_is_fast("cpu") == (share <= device.BF16_FAST_SHARE)
    device.cpu_bf16_share.cache_clear()
    for measured, fast in ((0.4, True), (0.8, True), (1.3, False)):
        monkeypatch.setattr(device, "cpu_bf16_share", lambda m=measured: m)
        assert device.bf16_is_fast("cpu") is fast
        with autocast("cpu", "auto"):
            assert (torch.randn(4, 4) @ torch.randn(4, 4)).dtype == (torch.bfloat16 if fast else torch.float32)
    monkeypatch.setattr(fit_default, "cpu_bf16_share", lambda: 1.3)
    monkeypatch.setattr(fit_default, "bf16_is_fast", lambda dev: False)
    assert "native bf16 runs in 1.3x fp32's time, no faster" in fit_default.choose_preset("cpu")[1]
