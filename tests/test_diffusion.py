"""Noise schedule, training (loss, exact resume, checkpoints), DDPM / DDIM sampling, masked sampling."""

import io

import numpy as np
import pytest
import torch

from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.model.diffusion import (
    DiffusionTrainer,
    diffusion_loss,
    fit_diffusion,
    predict_clean,
    sample,
    soft_mask,
)
from sin3dm_lite.model.schedule import NoiseSchedule, ddim_timesteps, sampling_timesteps, start_step
from sin3dm_lite.model.triplane import Triplane

from .conftest import LATENT_RES, tiny_diffusion_cfg


@pytest.fixture(scope="module")
def trained(h0):
    """A tiny model on a 200-step schedule (so that DDPM sampling is quick)."""
    trainer = DiffusionTrainer(h0, tiny_diffusion_cfg(timesteps=200, steps=30), device="cpu")
    trainer.run(progress=False)
    return trainer


# ------------------------------------------------------------------ schedule
def test_schedule_values():
    s = NoiseSchedule()
    assert s.betas[0].item() == pytest.approx(1e-4) and s.betas[-1].item() == pytest.approx(0.02)
    ac = s.alphas_cumprod
    assert len(ac) == 1000 and (ac[1:] < ac[:-1]).all() and 0 < ac[-1] < 1e-4 and ac[0] < 1
    assert (s.posterior_variance >= 0).all() and s.posterior_variance[0] == 0
    assert s.alpha_bar(-1).item() == 1.0 and s.alpha_bar(torch.tensor([0, 999])).shape == (2,)


def test_q_sample_and_its_inverses(h0):
    s = NoiseSchedule()
    noise = Triplane.randn_like(h0, torch.Generator().manual_seed(0))
    x_start = s.q_sample(h0, torch.tensor([0]), noise)
    assert all(torch.allclose(a, b, atol=0.05) for a, b in zip(x_start.planes, h0.planes))  # t=0: ≈ x0
    x_end = s.q_sample(h0, 999, noise)
    assert all(torch.allclose(a, b, atol=0.02) for a, b in zip(x_end.planes, noise.planes))  # t=T-1: ≈ noise
    t = torch.tensor([500])
    x_t = s.q_sample(h0, t, noise)
    assert torch.allclose(s.predict_x0(x_t, t, noise).yz, h0.yz, atol=1e-5)
    assert torch.allclose(s.predict_eps(x_t, t, h0).xz, noise.xz, atol=1e-5)


# ------------------------------------------------------------------ training
def test_loss_decreases_on_a_tiny_fit(h0):
    model, history = fit_diffusion(h0, tiny_diffusion_cfg(), device="cpu", progress=False)
    assert list(history) == ["loss"] and len(history["loss"]) == 60
    assert np.mean(history["loss"][-10:]) < 0.6 * np.mean(history["loss"][:10])
    assert not model.training


@pytest.mark.parametrize("prediction", ["eps", "x0"])
def test_an_oracle_model_has_zero_loss_and_gives_back_x0(h0, prediction):
    s = NoiseSchedule()
    x0 = h0.repeat(3)
    t = torch.tensor([0, 500, 999])
    noise = Triplane.randn_like(x0, torch.Generator().manual_seed(0))
    answer = noise if prediction == "eps" else x0

    def oracle(x, step):  # always predicts the training target exactly
        return answer

    assert diffusion_loss(oracle, s, x0, t, noise, prediction).item() == 0
    x_t = s.q_sample(x0, t, noise)
    clean = predict_clean(oracle, s, x_t, t, prediction, clip=False)
    assert all(torch.allclose(a, b, atol=1e-4) for a, b in zip(clean.planes, x0.planes))


def test_eps_prediction_trains(h0):
    trainer = DiffusionTrainer(h0, tiny_diffusion_cfg(prediction="eps", steps=5), device="cpu")
    trainer.run(progress=False)
    assert len(trainer.history["loss"]) == 5 and np.isfinite(trainer.history["loss"]).all()
    with pytest.raises(Sin3DMInputError):
        DiffusionTrainer(h0, tiny_diffusion_cfg(prediction="v"), device="cpu")
    with pytest.raises(Sin3DMInputError):
        DiffusionTrainer(h0.repeat(2), tiny_diffusion_cfg(), device="cpu")
    with pytest.raises(Sin3DMInputError, match="precision 'fp16'"):
        DiffusionTrainer(h0, tiny_diffusion_cfg(precision="fp16"), device="cpu")


def test_bf16_training_keeps_fp32_weights(h0):
    """The paper preset's bf16 autocast trains (loss in fp32, weights and EMA in fp32), about as fp32 does."""
    fp32 = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=30), device="cpu", seed=1)
    bf16 = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=30, precision="bf16", ema_decay=0.9), device="cpu", seed=1)
    fp32.run(progress=False)
    bf16.run(progress=False)
    assert all(p.dtype == torch.float32 for p in [*bf16.model.parameters(), *bf16.ema.parameters()])
    first, last = np.mean(bf16.history["loss"][:5]), np.mean(bf16.history["loss"][-5:])
    assert np.isfinite(bf16.history["loss"]).all() and last < 0.85 * first  # it learns ...
    assert last == pytest.approx(np.mean(fp32.history["loss"][-5:]), rel=0.1)  # ... about as fp32 does
    assert bf16.history["loss"] != fp32.history["loss"]  # the autocast is really on


def test_compile_is_asked_for_on_every_device_and_trains_the_same_weights(h0, monkeypatch):
    """``compile=True`` trains through ``torch.compile(model)`` on a CPU too (it pays on long fits there as well);
    the compiled forward shares the module's weights, so the checkpoint and the sampler see what it trained."""
    compiled = []

    def fake_compile(module):  # torch.compile's wrapper, without minutes of compiling in a test
        compiled.append(module)
        return lambda *args, **kwargs: module(*args, **kwargs)

    monkeypatch.setattr(torch, "compile", fake_compile)
    tr = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=3, compile=True), device="cpu", seed=2)
    assert compiled == [tr.model] and tr.train_forward is not tr.model
    plain = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=3), device="cpu", seed=2)
    assert plain.train_forward is plain.model and len(compiled) == 1
    tr.run(progress=False)
    plain.run(progress=False)
    assert tr.history["loss"] == plain.history["loss"]
    for a, b in zip(tr.model.parameters(), plain.model.parameters()):
        assert torch.equal(a, b)


def test_a_failed_compile_falls_back_to_the_plain_denoiser(h0):
    """A machine without a working torch.compile toolchain (Triton, a C++ compiler) trains eagerly, with one warning."""
    tr = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=3), device="cpu")

    def broken(*args, **kwargs):
        raise RuntimeError("no Triton here")

    tr.train_forward = broken  # what a compiled forward does on such a machine
    with pytest.warns(UserWarning, match="torch.compile of the denoiser failed"):
        tr.step()
    assert tr.train_forward is tr.model and tr.step_count == 1
    eager = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=3), device="cpu")
    eager.step()
    assert tr.history["loss"] == eager.history["loss"]  # the same batch, trained eagerly
    for a, b in zip(tr.model.parameters(), eager.model.parameters()):
        assert torch.equal(a, b)
    tr.train_forward = broken  # once a compiled step ran, an error is the training's own: it is raised
    with pytest.raises(RuntimeError, match="no Triton"):
        tr.step()


def test_resume_is_bit_identical_and_checkpoints_load_weights_only(h0):
    cfg = tiny_diffusion_cfg(steps=12, ema_decay=0.9)
    straight = DiffusionTrainer(h0, cfg, device="cpu", seed=3)
    straight.run(progress=False)

    first = DiffusionTrainer(h0, cfg, device="cpu", seed=3)
    seen = []
    first.run(until_step=5, progress=False, callback=lambda tr: seen.append(tr.step_count))
    assert seen == [1, 2, 3, 4, 5]
    buf = io.BytesIO()
    torch.save(first.state_dict(), buf)
    buf.seek(0)
    sd = torch.load(buf, weights_only=True)
    first.run(progress=False)  # the saved snapshot must not change when training goes on

    resumed = DiffusionTrainer(h0, cfg, device="cpu", seed=99)  # different seed: everything comes from sd
    resumed.load_state_dict(sd)
    assert resumed.step_count == 5
    resumed.run(progress=False)
    rebuilt = DiffusionTrainer.from_state_dict(sd)
    rebuilt.run(progress=False)
    for other in (first, resumed, rebuilt):
        assert other.history == straight.history
        for a, b in zip(straight.model.parameters(), other.model.parameters()):
            assert torch.equal(a, b)
        for a, b in zip(straight.ema.parameters(), other.ema.parameters()):
            assert torch.equal(a, b)


def test_model_for_sampling_is_ema_or_raw(h0):
    with_ema = DiffusionTrainer(h0, tiny_diffusion_cfg(ema_decay=0.9, steps=2), device="cpu")
    before = [p.detach().clone() for p in with_ema.model.parameters()]  # the EMA starts as a copy
    with_ema.step()
    assert with_ema.model_for_sampling is with_ema.ema
    for ema, w0, w1 in zip(with_ema.ema.parameters(), before, with_ema.model.parameters()):
        assert torch.allclose(ema, 0.9 * w0 + 0.1 * w1)  # ema = decay·ema + (1 - decay)·new weights
    raw = DiffusionTrainer(h0, tiny_diffusion_cfg(steps=2), device="cpu")
    assert raw.ema is None and raw.model_for_sampling is raw.model and not raw.model.training
    assert raw.scheduler.get_last_lr()[0] == pytest.approx(2e-3)
    raw.run(progress=False)
    assert raw.scheduler.get_last_lr()[0] == pytest.approx(0.0)  # annealed linearly to 0 over cfg.steps


# ------------------------------------------------------------------ sampling
def test_ddim_timesteps():
    assert ddim_timesteps(1000, 1) == [999]
    ts = ddim_timesteps(1000, 50)
    assert len(ts) == 50 and ts[0] == 999 and ts[-1] == 0 and all(a > b for a, b in zip(ts, ts[1:]))
    assert ddim_timesteps(10, 10) == list(range(9, -1, -1))
    with pytest.raises(Sin3DMInputError):
        ddim_timesteps(10, 11)


@pytest.mark.parametrize("method", ["ddim", "ddpm"])
def test_sampling_shapes_range_and_determinism(trained, method):
    model, sched = trained.model_for_sampling, trained.schedule
    a = sample(model, sched, LATENT_RES, n=2, method=method, steps=8, seed=5, progress=False)
    b = sample(model, sched, LATENT_RES, n=2, method=method, steps=8, seed=5, progress=False)
    c = sample(model, sched, LATENT_RES, n=2, method=method, steps=8, seed=6, progress=False)
    assert a.batch == 2 and a.channels == 4 and a.resolution == LATENT_RES
    assert all(p.abs().max() <= 1.0 for p in a.planes)  # the last step returns the clipped x0
    assert all(torch.equal(p, q) for p, q in zip(a.planes, b.planes))
    assert not torch.equal(a.xy, c.xy)
    assert not torch.equal(a.xy[0], a.xy[1])


def test_denoised_fn_changes_each_steps_estimate_before_the_step_uses_it(trained):
    """``denoised_fn(x0, t)``, improved-diffusion's hook: called once a step with that step's clipped estimate and
    time step; what it returns is what the step uses and records. The identity gives the paper's sampler, bit for bit."""
    model, sched = trained.model_for_sampling, trained.schedule
    args = dict(n=2, steps=8, seed=5, progress=False, return_intermediates=8)
    plain, theirs = sample(model, sched, LATENT_RES, **args)
    seen = []
    same, _ = sample(model, sched, LATENT_RES, denoised_fn=lambda x0, t: seen.append((x0, t)) or x0, **args)
    assert [t for _, t in seen] == sampling_timesteps(sched, "ddim", 8)
    assert all(torch.equal(x0.xy.cpu(), d["x0"].xy) for (x0, _), d in zip(seen, theirs))
    assert all(torch.equal(p, q) for p, q in zip(same.planes, plain.planes))
    halved, ours = sample(model, sched, LATENT_RES, denoised_fn=lambda x0, t: x0 * 0.5, **args)
    assert not torch.equal(halved.xy, plain.xy)
    torch.testing.assert_close(halved.xy, ours[-1]["x0"].xy)  # DDIM's last step lands on the changed estimate
    assert float(ours[-1]["x0"].xy.abs().max()) <= 0.5  # the clipped estimate, halved
    assert all(torch.equal(p, q) for p, q in zip(ours[0]["x_t"].planes, theirs[0]["x_t"].planes))  # the same start


def test_intermediates(trained):
    model = trained.model_for_sampling
    x, inter = sample(model, trained.schedule, LATENT_RES, n=1, steps=10, return_intermediates=4, progress=False)
    assert [d["step"] for d in inter] == [0, 3, 6, 9] and inter[0]["t"] == 199 and inter[-1]["t"] == 0
    assert set(inter[0]) == {"step", "t", "x_t", "x0"}
    assert isinstance(inter[1]["x_t"], Triplane) and inter[1]["x0"].device.type == "cpu"
    assert torch.equal(inter[-1]["x0"].xy, x.xy)  # DDIM's last step lands on its x0
    _, inter = sample(model, trained.schedule, LATENT_RES, steps=10, return_intermediates=[0, -1], progress=False)
    assert [d["step"] for d in inter] == [0, 9]


def test_sampling_at_another_resolution_and_eps_prediction(trained):
    x = sample(trained.model_for_sampling, trained.schedule, (13, 7, 10), n=1, steps=5, progress=False)
    assert x.resolution == (13, 7, 10)
    x = sample(trained.model_for_sampling, trained.schedule, (6, 9, 5), steps=5, progress=False, prediction="eps")
    assert x.resolution == (6, 9, 5) and all(torch.isfinite(p).all() for p in x.planes)


@pytest.mark.parametrize("method", ["ddim", "ddpm"])
def test_mask_of_ones_returns_known_exactly(trained, h0, method):
    ones = h0.map(lambda p: torch.ones_like(p[:, :1]))
    model, sched = trained.model_for_sampling, trained.schedule
    x = sample(model, sched, LATENT_RES, n=2, method=method, steps=6, known=h0, mask=ones, progress=False)
    assert all(torch.equal(p, q.expand_as(p)) for p, q in zip(x.planes, h0.planes))


def test_soft_mask_and_partial_masked_sampling(trained, h0):
    m = soft_mask(LATENT_RES, box=((-1, -1, -1), (0, 1, 1)), border=0.5)  # keep the x < 0 half, blend 2 texels
    assert [tuple(p.shape) for p in m.planes] == [(1, 1, 8, 8)] * 3
    col = m.xy[0, 0, :, 3]  # along x: texel centres -0.875 ... 0.875
    assert torch.allclose(col, torch.tensor([1, 1, 1, 1, 0.75, 0.25, 0, 0.0]))
    assert torch.equal(m.yz, torch.ones_like(m.yz))  # the box spans all of y and z
    inv = soft_mask(h0, box=((-1, -1, -1), (0, 1, 1)), border=0.0, invert=True)
    assert torch.equal(inv.xy[0, 0, :, 0], torch.tensor([0, 0, 0, 0, 1, 1, 1, 1.0]))
    x = sample(trained.model_for_sampling, trained.schedule, LATENT_RES, n=2, steps=6, known=h0, mask=m, progress=False)
    keep = m.xy == 1
    assert torch.equal(x.xy[keep.expand_as(x.xy)], h0.xy.expand_as(x.xy)[keep.expand_as(x.xy)])
    assert not torch.equal(x.xy[:, :, 6:], h0.xy.expand_as(x.xy)[:, :, 6:])
    with pytest.raises(Sin3DMInputError):
        sample(trained.model_for_sampling, trained.schedule, LATENT_RES, known=h0, progress=False)


def test_triplane_mse_is_the_plane_mean_summed_over_planes():
    from sin3dm_lite.model.diffusion import triplane_mse

    a = Triplane.randn(1, 2, (3, 4, 5))
    b = a.map(lambda p: p + 0.5)
    b.xy[..., 0, 0] += 1.0  # one texel of xy off by 1.5 instead of 0.5
    expected = 0.25 + 0.25 + (0.25 * 11 + 2.25) / 12  # xy has 3 × 4 = 12 texels per channel
    assert float(triplane_mse(a, b)) == pytest.approx(expected)


# ------------------------------------------------------------------ diversity knob
def test_start_step_follows_the_noise_level():
    s = NoiseSchedule()
    assert start_step(s, 1.0) == 999 and start_step(s, 0.0) == -1
    assert [start_step(s, d) for d in (0.1, 0.5, 0.9)] == [100, 500, 899]  # the share of the reverse process
    assert start_step(s, 1e-6) == 0  # any setting above 0 runs at least the last step
    for bad in (-0.01, 1.01, float("nan"), True, "1"):
        with pytest.raises(Sin3DMInputError, match="diversity"):
            start_step(s, bad)


def test_sampling_timesteps_from_a_start_step():
    s = NoiseSchedule()
    assert sampling_timesteps(s, "ddim", 50) == ddim_timesteps(1000, 50)
    low = sampling_timesteps(s, "ddim", 50, 199)
    assert low[0] == 199 and low[-1] == 0 and len(low) == 10  # the same spacing over a fifth of the range
    assert sampling_timesteps(s, "ddim", 50, 5) == [5]
    assert sampling_timesteps(s, "ddpm", 50, 99) == list(range(99, -1, -1))


@pytest.mark.parametrize("method", ["ddim", "ddpm"])
def test_diversity_moves_samples_from_the_start_latent_to_noise(h0, method):
    """With the exact x0 estimate for N(0, I) data (x0 = √ᾱ·x_t) the sampler keeps x_t0 almost as it is,
    so a sample is ``√ᾱ·start + √(1-ᾱ)·noise`` at t0: its distance to the start grows with the knob."""
    s = NoiseSchedule(timesteps=200)

    def gaussian_oracle(x, t):
        return x.map(lambda p: p * s.alpha_bar(t).sqrt().reshape(-1, 1, 1, 1).float())

    gaussian_oracle.cfg = None
    start = h0.map(lambda p: p * 0 + 0.8)  # a constant latent, far from pure noise
    dist = []
    for d in (0.0, 0.05, 0.3, 0.6, 1.0):
        out = sample(
            gaussian_oracle,
            s,
            LATENT_RES,
            n=8,
            latent_channels=4,
            method=method,
            steps=20,
            seed=0,
            clip=False,
            device="cpu",
            prediction="x0",
            start=start,
            diversity=d,
            progress=False,
        )
        dist.append(float(sum(((p - q) ** 2).mean() for p, q in zip(out.planes, start.planes))))
    assert dist[0] == 0.0
    assert all(a < b for a, b in zip(dist, dist[1:])), dist
    assert dist[-1] > 0.9 * (0.8**2 + 1) * 3  # pure noise: |start|² + 1 per plane
    with pytest.raises(Sin3DMInputError, match="start"):
        sample(gaussian_oracle, s, LATENT_RES, n=1, latent_channels=4, device="cpu", diversity=0.5, progress=False)


# ------------------------------------------------------------------ the latent scaled for the diffusion
def test_unit_latent_scale_is_found_at_training_and_trains_on_the_scaled_latent(h0):
    """``latent_scale=0`` becomes the number that gives the latent unit variance, recorded in the trainer's and the
    denoiser's config; the loss is the one a plain trainer gets on the latent multiplied by it (same seed)."""
    scaled = DiffusionTrainer(h0, tiny_diffusion_cfg(latent_scale=0.0), device="cpu")
    s = scaled.cfg.latent_scale
    values = torch.cat([p.flatten() for p in h0.planes])
    assert s == pytest.approx(1 / float(values.std()), rel=1e-6) and scaled.model.cfg.latent_scale == s
    assert torch.cat([p.flatten() for p in (h0 * s).planes]).std().item() == pytest.approx(1.0, rel=1e-5)
    plain = DiffusionTrainer(h0 * s, tiny_diffusion_cfg(latent_scale=1.0), device="cpu")
    assert scaled.losses()["loss"].item() == pytest.approx(plain.losses()["loss"].item(), rel=1e-6)
    assert all(torch.equal(a, b) for a, b in zip(scaled.h0.planes, h0.planes))  # the checkpoint keeps the latent


def _scaled_model(fn, scale: float):
    """A stand-in denoiser ``fn(x_t, t)`` whose config says it walks in units of the latent times ``scale``."""
    fn.cfg = tiny_diffusion_cfg(latent_scale=scale)
    return fn


def test_sampling_with_a_scaled_denoiser_takes_and_gives_the_encoders_units(h0):
    """The walk runs in the denoiser's units: an oracle that always answers ``scale · h0`` (outside [-1, 1], which
    the sampler must not clip there) gives back ``h0``; ``denoised_fn`` and the intermediates see ``h0`` too."""
    scale, s = 3.0, NoiseSchedule(timesteps=200)
    target = h0.map(lambda p: p.clamp(-0.9, 0.9))
    oracle = _scaled_model(lambda x, t: (target * scale).repeat(x.batch), scale)
    seen = []

    def look(x0, t):
        seen.append(max(float(p.abs().max()) for p in x0.planes))
        return x0

    out, steps = sample(
        oracle, s, LATENT_RES, n=2, latent_channels=4, steps=5, device="cpu", denoised_fn=look,
        return_intermediates=2, progress=False,
    )  # fmt: skip
    assert all(torch.allclose(p, q.expand_as(p), atol=1e-5) for p, q in zip(out.planes, target.planes))
    assert max(seen) <= 0.9 + 1e-6 and len(seen) == 5
    assert all(torch.allclose(p, q.expand_as(p), atol=1e-5) for p, q in zip(steps[-1]["x0"].planes, target.planes))


def test_a_scaled_denoiser_starts_from_the_start_latent_in_its_own_units(h0):
    """Below diversity 1 the start latent is noised in the denoiser's units: an identity denoiser barely moves
    it, and the sample comes back as the start (not the start divided or multiplied by the scale)."""
    scale, s = 4.0, NoiseSchedule(timesteps=200)
    start = h0.map(lambda p: p.clamp(-0.9, 0.9))
    identity = _scaled_model(lambda x, t: x, scale)
    out = sample(identity, s, LATENT_RES, n=1, latent_channels=4, steps=5, device="cpu", start=start, diversity=0.01,
                 progress=False)  # fmt: skip
    err = max(float((p - q).abs().max()) for p, q in zip(out.planes, start.planes))
    assert err < 0.05, err
    with pytest.raises(Sin3DMInputError, match="latent_scale 0"):
        sample(_scaled_model(lambda x, t: x, 0.0), s, LATENT_RES, n=1, latent_channels=4, device="cpu", progress=False)
