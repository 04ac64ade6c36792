"""The two trainers have one shape: step/run, history, checkpoint layout, generator, exact resume."""

import io

import pytest
import torch

from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.model import training
from sin3dm_lite.model.autoencoder import AutoencoderTrainer, TriplaneAutoencoder
from sin3dm_lite.model.diffusion import DiffusionTrainer
from sin3dm_lite.model.training import FUSED_CPU_ADAMW, TRAINER_FORMAT, Trainer
from sin3dm_lite.model.unet import TriplaneUNet

from .conftest import tiny_ae_cfg, tiny_diffusion_cfg

COMMON_KEYS = {"format", "kind", "model", "optimizer", "scheduler", "generator", "step", "history", "config", "seed"}


def make(kind, box_grid, h0, seed=0, **kw):
    if kind == "autoencoder":
        return AutoencoderTrainer(box_grid, tiny_ae_cfg(steps=6, points_per_step=512, **kw), seed=seed)
    return DiffusionTrainer(h0, tiny_diffusion_cfg(steps=6, **kw), device="cpu", seed=seed)


def reloaded(sd: dict) -> dict:
    buf = io.BytesIO()
    torch.save(sd, buf)
    buf.seek(0)
    return torch.load(buf, weights_only=True)


@pytest.mark.parametrize("kind", ["autoencoder", "diffusion"])
def test_a_cpu_trainer_takes_the_fused_adamw_step_which_is_adamw(kind, box_grid, h0, monkeypatch):
    """On a CPU the trainers use PyTorch's fused AdamW (one pass over all parameters) where the installed PyTorch
    has it; its step is AdamW's: the same weights after a few steps as the per-tensor loop, to rounding.

    A bias just before a normalisation (the encoder's, a plane block's first convolution) has no gradient but
    rounding's (about 1e-10): Adam divides it by its own size and moves the bias about ±lr on the noise's sign, so
    two implementations agree there only in how far it moved (on an AVX2 CPU 1.2e-4 after 3 steps)."""
    fused = make(kind, box_grid, h0)
    assert fused.optimizer.defaults["fused"] is (True if FUSED_CPU_ADAMW else None)
    monkeypatch.setattr(training, "FUSED_CPU_ADAMW", False)
    plain = make(kind, box_grid, h0)
    assert plain.optimizer.defaults["fused"] is None
    for tr in (fused, plain):
        tr.run(until_step=3, progress=False)
    lr = max(g["initial_lr"] for g in plain.optimizer.param_groups)
    for a, b in zip(fused.model.parameters(), plain.model.parameters()):
        if b.grad is not None and b.grad.abs().max() < 1e-8:  # rounding's gradient: at most lr a step either way
            assert (a - b).abs().max() <= 2 * 3 * lr
        else:  # a step moves a weight by about lr (1e-3): the two agree far closer
            torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-3)


@pytest.mark.parametrize("kind", ["autoencoder", "diffusion"])
def test_step_run_history_and_checkpoint_have_one_shape(kind, box_grid, h0):
    tr = make(kind, box_grid, h0)
    assert isinstance(tr, Trainer) and tr.kind == kind and isinstance(tr.generator, torch.Generator)
    loss = tr.step()
    assert isinstance(loss, float) and loss == tr.history["loss"][-1] and tr.step_count == 1
    seen = []
    assert tr.run(until_step=4, progress=False, callback=lambda t: seen.append(t.step_count)) is tr.history
    assert seen == [2, 3, 4]
    tr.run(until_step=100, progress=False)  # never past cfg.steps
    assert tr.step_count == 6
    assert "loss" in tr.history and all(len(v) == 6 and all(type(x) is float for x in v) for v in tr.history.values())
    assert set(tr.history) == ({"loss", "sdf", "color"} if kind == "autoencoder" else {"loss"})
    sd = reloaded(tr.state_dict())
    extras = {"ema", "h0"} if kind == "diffusion" else set()
    assert set(sd) == COMMON_KEYS | extras
    assert sd["format"] == TRAINER_FORMAT and sd["kind"] == kind and sd["step"] == 6 and sd["seed"] == 0
    assert sd["config"]["steps"] == 6
    assert {k: v.tolist() for k, v in sd["history"].items()} == tr.history


@pytest.mark.parametrize("kind", ["autoencoder", "diffusion"])
def test_interrupted_and_resumed_equals_uninterrupted(kind, box_grid, h0):
    straight = make(kind, box_grid, h0, seed=3)
    straight.run(progress=False)
    first = make(kind, box_grid, h0, seed=3)
    first.run(until_step=2, progress=False)
    sd = reloaded(first.state_dict())
    resumed = make(kind, box_grid, h0, seed=7)  # another seed: the checkpoint sets everything
    resumed.load_state_dict(sd)
    assert resumed.step_count == 2 and resumed.history == first.history
    resumed.run(progress=False)
    assert resumed.history == straight.history
    for a, b in zip(straight.model.state_dict().values(), resumed.model.state_dict().values()):
        assert torch.equal(a, b)
    assert torch.equal(straight.generator.get_state(), resumed.generator.get_state())


def test_initial_weights_come_from_the_seed_and_leave_the_global_rng_alone(box_grid, h0):
    state = torch.get_rng_state()
    ae = make("autoencoder", box_grid, h0, seed=5)
    dm = make("diffusion", box_grid, h0, seed=5)
    assert torch.equal(torch.get_rng_state(), state)
    torch.manual_seed(5)  # what the autoencoder trainer did before the shared base class: the same weights
    ref_ae = TriplaneAutoencoder(ae.cfg, box_grid.shape, box_grid.threshold, box_grid.color.shape[-1])
    torch.manual_seed(5)
    ref_dm = TriplaneUNet(h0.channels, dm.cfg)
    for tr, ref in ((ae, ref_ae), (dm, ref_dm)):
        for a, b in zip(tr.model.state_dict().values(), ref.state_dict().values()):
            assert torch.equal(a, b)


def test_checkpoints_of_another_trainer_or_layout_are_refused(box_grid, h0):
    ae, dm = make("autoencoder", box_grid, h0), make("diffusion", box_grid, h0)
    with pytest.raises(Sin3DMInputError, match="'diffusion' checkpoint, not a 'autoencoder'"):
        ae.load_state_dict(dm.state_dict())
    with pytest.raises(Sin3DMInputError, match="'autoencoder' checkpoint, not a 'diffusion'"):
        dm.load_state_dict(ae.state_dict())
    old_ae = {
        "model": ae.model.state_dict(),
        "opt": {},
        "sched": {},
        "gen": ae.generator.get_state(),
        "step": 0,
        "history": {"loss": torch.zeros(0, dtype=torch.float64)},
    }  # the layout before TRAINER_FORMAT
    with pytest.raises(Sin3DMInputError, match="older version"):
        ae.load_state_dict(old_ae)
    old_dm = {k: v for k, v in dm.state_dict().items() if k not in ("format", "kind", "step")} | {"step_count": 0}
    with pytest.raises(Sin3DMInputError, match="older version"):
        DiffusionTrainer.from_state_dict(old_dm)
    with pytest.raises(Sin3DMInputError, match="sin3dm-lite-trainer/1"):
        dm.load_state_dict({**dm.state_dict(), "format": "sin3dm-lite-trainer/1"})


def test_the_autoencoder_rates_decay_to_the_configs_factor_by_the_last_step(box_grid, h0):
    """Both learning rates (geometry, texture) fall exponentially to ``lr_final_factor`` of their start at the run's
    last step: the paper's 0.1 over its 25,000 steps; the CPU presets, a tenth as long or less, decay to √0.1."""
    from sin3dm_lite.presets import get_preset

    trainer = make("autoencoder", box_grid, h0, lr_final_factor=0.316)
    trainer.run(until_step=6)
    geo, tex = trainer.scheduler.get_last_lr()
    assert geo == pytest.approx(1e-3 * 0.316) and tex == pytest.approx(5e-3 * 0.316)
    assert get_preset("paper").autoencoder.lr_final_factor == 0.1
    for name in ("small", "quick", "detail", "fine"):
        assert get_preset(name).autoencoder.lr_final_factor == pytest.approx(0.1**0.5, abs=1e-3)
