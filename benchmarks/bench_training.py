"""Seconds per training step, ours vs straightforward implementations of the paper's layers.

    python benchmarks/bench_training.py [--presets tiny small detail paper] [--steps 5] [--threads 2] [--compile]
    python benchmarks/bench_training.py --grid [--resolutions 128 256] [--faces 77000]   # the grid stage
    python benchmarks/bench_training.py --flops [PRESET] [--threads 1] [--steps 3] [--compile]   # FLOP/s per stage
    python benchmarks/bench_training.py --flops paper --device cuda [--dims 256 128 96]   # the same on a GPU

Per stage of a fit: ``--grid`` times the first stage, mesh -> grid, on a bumpy textured sphere (77k faces, open);
without it, one training step of each network:

Autoencoder step (one batch of points, forward + backward + AdamW):
  * ours        – the decoder's per-plane ResNet blocks run once per step, then all points are looked up (fp32);
  * bf16        – ours under torch.autocast(bfloat16): the MLPs' matrix products (≈ 70 % of the step) in bf16;
  * per-chunk   – the original code's pattern: the points are decoded in chunks of 8,192 and the
                  plane convolutions are recomputed for every chunk.
Diffusion step (a batch of noisy copies of the latent, forward + backward + AdamW):
  * ours        – three Conv2d per TriplaneConv, one per plane, each at its own size;
  * canvas      – the three planes packed side by side into one zero-padded image and one Conv2d
                  (the "treat the triplane as an image" shortcut);
  * channels-last – ours with torch.channels_last memory format;
  * bf16        – ours with ``DiffusionConfig(precision="bf16")`` (the CPU presets train it in fp32; ``paper``
                  picks bf16 where it is native);
  * compiled    – with --compile: ours after torch.compile of the U-Net's forward (the compile time is printed
                  apart; about 96 s for `detail` on 2 cores, for 9 % per step).
The paper preset runs at its real size (256 grid / 128 latent, 65,536 points): slow on a CPU.

``--flops``: the ``paper`` preset's networks on a 64 × 32 × 24 grid (latent 32 × 16 × 12; issue 63's setting;
``--flops detail``: another preset's networks, points and batch on a grid of its resolution shaped like a round
tower, 1 × 0.92 × 0.92), per stage (autoencoder step, denoiser step at the preset's batch, one DDIM sampling step
of one sample, the full decode of a latent to that grid with colour): seconds (the least of ``--steps`` runs, process CPU time, so a
busy machine's waits do not count), the FLOPs, the achieved GFLOP/s and its share of the CPU's peak, in fp32,
in fp32 with the decoder's fast paths off (``model/pointops.py``: the plain modules) and under bf16 autocast.
FLOPs: the matrix products and convolutions of one forward pass as torch's FlopCounterMode counts them from
their shapes (2 per multiply-add; elementwise work not counted); a training step counts 3 × its forward (the
backward's two products per forward product), a sampling step and the decode their forward. The peak:
:func:`cpu_peak` (cores used × clock × vector lanes × 2 FMA units × 2), beside a measured ceiling, the
GFLOP/s of one [2048, 256] × [256, 256] product on this machine. With ``--device cuda`` the same stages run on
the GPU (wall time with a device sync; ``--dims`` sets the grid, e.g. the paper's 256 × 128 × 96), beside
:func:`gpu_peak` (SMs × the highest SM clock × the architecture's FLOPs per clock per SM, for its fp32 cores and
its TF32 and bf16 tensor cores) and the measured ceilings of one 8,192² product in fp32, TF32 and bf16.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import subprocess
import time
import tracemalloc
from collections import defaultdict
from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F
import trimesh
from torch.utils.flop_counter import FlopCounterMode, register_flop_formula

from sin3dm_lite.app.device import bf16_is_fast
from sin3dm_lite.auto.fit_default import timing_grid
from sin3dm_lite.data.grid import ShapeGrid, mesh_to_grid
from sin3dm_lite.data.mesh import Material, Normalization, TexturedMesh
from sin3dm_lite.kernels import pointops
from sin3dm_lite.model.autoencoder import AutoencoderTrainer, sdf_loss
from sin3dm_lite.model.decode import decode_grid
from sin3dm_lite.model.diffusion import DiffusionTrainer, sample
from sin3dm_lite.model.triplane import Triplane
from sin3dm_lite.model.unet import TriplaneConv, cross_plane_inputs
from sin3dm_lite.presets import get_preset


def synthetic_grid(dims, n_points: int) -> ShapeGrid:
    """A sphere-ish TSDF grid of the given size (timings do not depend on the content)."""
    dims = np.array(dims)
    half = dims / dims.max()
    aabb = np.concatenate([-half, half]).astype(np.float32)
    thr = 3 * 2 / dims.max()
    g = ShapeGrid(
        np.zeros(tuple(dims), np.float32), np.zeros((*dims, 3), np.float32), aabb, thr, Normalization.identity()
    )
    c = g.voxel_centers()
    g.sdf = np.clip(np.linalg.norm(c, axis=-1) - 0.5 * half.min(), -thr, thr).astype(np.float32)
    g.color = np.where((np.abs(g.sdf) < thr)[..., None], (c + 1) / 2, 0).astype(np.float32)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(n_points, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True) * 0.5 * half.min()
    g.points = p.astype(np.float32)
    g.point_sdf = np.zeros(n_points, np.float32)
    g.point_color = ((p + 1) / 2).astype(np.float32)
    return g


def per_chunk_step(tr: AutoencoderTrainer, chunk: int = 8192) -> float:
    """The autoencoder step with the plane convolutions recomputed for every chunk of points."""
    cfg = tr.cfg
    p, s_gt, c_gt = tr.sampler(cfg.points_per_step, cfg.grid_fraction, tr.generator)
    tr.optimizer.zero_grad(set_to_none=True)
    total = 0.0
    for a in range(0, len(p), chunk):
        h = tr.model.encode(tr.grid_t)
        prep = tr.model.decoder.prepare(h)  # recomputed per chunk
        q, sg, cg = p[a : a + chunk], s_gt[a : a + chunk], c_gt[a : a + chunk]
        s = tr.model.decoder.query_sdf(prep, q[None])[0]
        band = sg.abs() < tr.grid.threshold
        c = tr.model.decoder.query_color(prep, q[band][None])[0]
        loss = (sdf_loss(s, sg, tr.grid.threshold) + (c - cg[band]).abs().mean()) * len(q) / len(p)
        loss.backward()
        total += float(loss.detach())
    tr.optimizer.step()
    tr.scheduler.step()
    return total


class CanvasConv(torch.nn.Module):
    """One Conv2d over the three planes packed into a single zero-padded canvas [B, C, max(X,Y), Y+2Z]."""

    def __init__(self, ref: TriplaneConv):
        super().__init__()
        c = ref.convs[0]
        self.rollout = ref.rollout
        self.conv = torch.nn.Conv2d(c.in_channels, c.out_channels, c.kernel_size, padding=c.padding)

    def forward(self, tp: Triplane) -> Triplane:
        if self.rollout:
            tp = cross_plane_inputs(tp)
        (x, y, z), h = tp.resolution, max(tp.resolution[0], tp.resolution[1])
        pad = lambda p: F.pad(p, (0, 0, 0, h - p.shape[2]))  # noqa: E731
        out = self.conv(torch.cat([pad(tp.xy), pad(tp.xz), pad(tp.yz)], dim=3))
        return Triplane(out[:, :, :x, :y], out[:, :, :x, y : y + z], out[:, :, :y, y + z :])


def swap_convs(module: torch.nn.Module) -> None:
    for name, child in module.named_children():
        if isinstance(child, TriplaneConv):
            setattr(module, name, CanvasConv(child))
        else:
            swap_convs(child)


def bumpy_textured_sphere(target_faces: int) -> TexturedMesh:
    """An icosphere with bumps, cut to ~target_faces (open; all 81,920 = closed), with a striped UV texture."""
    m = trimesh.creation.icosphere(subdivisions=6)  # 81,920 faces
    m = trimesh.Trimesh(m.vertices, m.faces[:target_faces], process=False)  # an open mesh, as assets often are
    v = np.asarray(m.vertices)
    v = v * (1 + 0.08 * np.sin(7 * v[:, :1]) * np.cos(5 * v[:, 1:2]))
    f = np.asarray(m.faces, np.int64)
    uv = np.stack([np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi) + 0.5, v[:, 2] / 2 + 0.5], 1)
    yy, xx = np.mgrid[0:512, 0:512] / 512
    tex = np.stack([0.5 + 0.5 * np.sin(40 * yy), 0.5 + 0.5 * np.sin(25 * xx), 0.5 + 0 * xx], -1).astype(np.float32)
    return TexturedMesh(
        v,
        f,
        np.zeros(len(f), np.int64),
        [Material(base_color=np.ones(4, np.float32), image=tex)],
        face_uvs=uv[f].astype(np.float32),
        name="bumpy_sphere",
    )


def grid_times(resolutions: list[int], faces: int, points: int) -> None:
    """Mesh -> grid at each resolution, without and with the near-surface training points, and peak numpy memory."""
    mesh = bumpy_textured_sphere(faces)
    print(f"mesh: {len(mesh.faces):,} faces, textured, {'closed' if len(mesh.faces) == 81_920 else 'open'}")
    mesh_to_grid(mesh, 32, n_surface_points=0, progress=False)  # warm-up (imports, first-call costs)
    for res in resolutions:
        for n in (0, points):
            tracemalloc.start()
            t = time.perf_counter()
            g = mesh_to_grid(mesh, res, n_surface_points=n, progress=False)
            dt = time.perf_counter() - t
            peak = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            what = "grid only" if n == 0 else f"+ {n:,} training points"
            print(f"grid {res:4d}: {g.shape} in {dt:6.2f} s  {what:28s} (peak numpy memory {peak:,.0f} MiB)")


def cpu_peak(threads: int) -> tuple[float, str]:
    """This CPU's fp32 peak in GFLOP/s and how it was derived: ``threads`` cores × the clock cpuinfo reports
    (the nominal one; turbo can run above it) × fp32 lanes (16 with AVX-512, 8 with AVX2, 4 otherwise) × 2 FMA
    units (assumed: server cores since Skylake-SP have two) × 2 flops per multiply-add."""
    text = open("/proc/cpuinfo").read() if os.path.exists("/proc/cpuinfo") else ""
    mhz = [float(m) for m in re.findall(r"^cpu MHz\s*:\s*([\d.]+)", text, re.M)]
    name = re.search(r"^model name\s*:\s*(.+)$", text, re.M)
    flags = set((re.search(r"^flags\s*:\s*(.+)$", text, re.M) or [None, ""])[1].split())
    lanes, isa = (16, "AVX-512") if "avx512f" in flags else (8, "AVX2") if "avx2" in flags else (4, "SSE")
    ghz = max(mhz) / 1000 if mhz else float("nan")
    peak = threads * ghz * lanes * 2 * 2
    how = (
        f"{name[1].strip() if name else 'unknown CPU'}: {threads} core(s) x {ghz:.2f} GHz (cpuinfo) x {lanes} fp32 "
        f"lanes ({isa}) x 2 FMA units (assumed) x 2 = {peak:.0f} GFLOP/s"
        f"{'; AMX-BF16 present' if 'amx_bf16' in flags else ''}"
    )
    return peak, how


def gemm_ceiling(repeats: int = 50) -> float:
    """GFLOP/s of one [2048, 256] × [256, 256] fp32 product (the best of ``repeats``, CPU time): what this core
    attains in one matrix product, turbo clock included."""
    a, b = torch.randn(2048, 256), torch.randn(256, 256)
    return 2 * 2048 * 256 * 256 / timed(lambda: a @ b, 1, warmup=2, repeats=repeats, cpu=True) / 1e9


#: dense FLOPs per clock per SM by compute capability: fp32 cores, TF32 and bf16 tensor cores (NVIDIA's
#: architecture whitepapers; 8.6/8.9 as on the workstation cards, whose GeForce siblings run half the tensor rate)
SM_FLOPS_PER_CLOCK = {
    (8, 0): (128, 1024, 2048),  # A100
    (8, 6): (256, 512, 1024),  # A40, RTX A6000
    (8, 9): (256, 512, 1024),  # L40, RTX 6000 Ada
    (9, 0): (256, 2048, 4096),  # H100, H200
}


def gpu_peak(dev: torch.device) -> tuple[dict[str, float], str]:
    """This GPU's peaks in GFLOP/s (``fp32``, ``tf32``, ``bf16``; dense) and how they were derived: SMs × the
    highest SM clock ``nvidia-smi`` reports × :data:`SM_FLOPS_PER_CLOCK`. NVIDIA's datasheets quote the tensor
    peaks at a lower clock (989 TFLOP/s bf16 dense for an H100/H200 SXM), so these are upper bounds."""
    props = torch.cuda.get_device_properties(dev)
    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=clocks.max.sm", "--format=csv,noheader,nounits", "-i", str(dev.index or 0)],
            capture_output=True,
            text=True,
            timeout=30,
            check=True,
        )
        ghz = float(out.stdout.split()[0]) / 1000
    except (OSError, subprocess.SubprocessError, ValueError, IndexError):
        ghz = getattr(props, "clock_rate", float("nan")) / 1e6  # kHz where torch has it
    rates = SM_FLOPS_PER_CLOCK.get((props.major, props.minor))
    if rates is None:
        return {}, f"{props.name}: compute capability {props.major}.{props.minor} not in SM_FLOPS_PER_CLOCK"
    peaks = {k: props.multi_processor_count * ghz * r for k, r in zip(("fp32", "tf32", "bf16"), rates)}
    how = (
        f"{props.name}: {props.multi_processor_count} SMs x {ghz:.2f} GHz (nvidia-smi's max SM clock) x "
        f"{rates[0]} / {rates[1]} / {rates[2]} FLOPs per clock per SM = fp32 {peaks['fp32'] / 1e3:.1f}, TF32 "
        f"{peaks['tf32'] / 1e3:.0f}, bf16 {peaks['bf16'] / 1e3:.0f} TFLOP/s (dense)"
    )
    return peaks, how


def gpu_ceilings(dev: torch.device, n: int = 8192) -> dict[str, float]:
    """GFLOP/s of one ``n``² × ``n``² product on ``dev`` in fp32, TF32 and bf16 (the mean of 10 after 3)."""
    a, b = torch.randn(n, n, device=dev), torch.randn(n, n, device=dev)
    old = torch.backends.cuda.matmul.allow_tf32
    res = {}
    try:
        for name, dtype, tf32 in (("fp32", torch.float32, False), ("tf32", torch.float32, True), ("bf16", None, False)):
            torch.backends.cuda.matmul.allow_tf32 = tf32
            x, y = (a, b) if dtype else (a.bfloat16(), b.bfloat16())
            res[name] = 2 * n**3 / timed(synced(lambda x=x, y=y: x @ y, dev), 10, warmup=3) / 1e9
    finally:
        torch.backends.cuda.matmul.allow_tf32 = old
    return res


def sync(dev: torch.device) -> None:
    """Wait for ``dev``'s queued work (nothing to wait for on a CPU)."""
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def synced(fn, dev: torch.device):
    """``fn`` followed by :func:`sync`, so that a wall clock times its work."""

    def run():
        out = fn()
        sync(dev)
        return out

    return run


def _linear_pointwise_flops(x_shape, w_shape, *args, **kwargs) -> int:
    """oneDNN's fused product (``kernels/bf16ops.linear_relu``), which FlopCounterMode does not know: ``2·M·N·K``."""
    return 2 * int(np.prod(x_shape[:-1])) * w_shape[0] * w_shape[1]


if hasattr(torch.ops.mkldnn, "_linear_pointwise"):
    with contextlib.suppress(RuntimeError):  # registered already (this script imported twice)
        register_flop_formula(torch.ops.mkldnn._linear_pointwise)(_linear_pointwise_flops)


def forward_flops(fn) -> float:
    """The matrix-product and convolution FLOPs of ``fn()`` (torch's FlopCounterMode, from the shapes)."""
    with FlopCounterMode(display=False) as counter:
        fn()
    return float(counter.get_total_flops())


def flops_stages(
    precision: str, steps: int, grid: ShapeGrid, preset: str = "paper", compiled: bool = False, device: str = "cpu"
) -> list[tuple[str, float, float]]:
    """``(stage, seconds, FLOPs)`` of each stage of ``preset``'s networks in ``precision`` ("fp32" or "bf16") on
    ``device`` (a CPU: process CPU time; a GPU: wall time after a sync); ``compiled``: the denoiser step through
    torch.compile too."""
    cfg, dev = get_preset(preset), torch.device(device)
    torch.manual_seed(0)
    ae = AutoencoderTrainer(grid, replace(cfg.autoencoder, precision=precision), device=dev)
    dm = DiffusionTrainer(ae.latent(), replace(cfg.diffusion, ema_decay=0.0, precision=precision, compile=False), dev)
    h0, model = dm.h0, dm.model
    with torch.no_grad():
        f_ae, f_dm = 3 * forward_flops(ae.losses), 3 * forward_flops(dm.losses)
    n_sample = 5
    ctx = (lambda: torch.autocast(dev.type, torch.bfloat16)) if precision == "bf16" else contextlib.nullcontext

    def sampling():
        with ctx():
            sample(model.eval(), dm.schedule, h0.resolution, steps=n_sample, progress=False)

    def decoding():
        with ctx():
            decode_grid(ae.model.decoder, h0, grid.aabb, max(grid.shape), with_color=True, coarse=None)

    def clock(fn):
        return timed(synced(fn, dev), steps, cpu=dev.type == "cpu", repeats=steps)

    f_sample, f_decode = forward_flops(sampling) / n_sample, forward_flops(decoding)
    rows = [
        ("autoencoder step", clock(ae.step), f_ae),
        ("denoiser step", clock(dm.step), f_dm),
        ("sampling step", clock(sampling) / n_sample, f_sample),
        ("decode to the grid", clock(decoding), f_decode),
    ]
    if compiled:  # the same denoiser through torch.compile (DiffusionConfig.compile), its compile timed apart
        dmc = DiffusionTrainer(dm.h0, replace(dm.cfg, compile=True), dev)
        t = time.perf_counter()
        synced(dmc.step, dev)()
        print(f"[{precision}] the denoiser compiled in {time.perf_counter() - t:.0f} s (wall)")
        rows.insert(2, ("denoiser step, compiled", clock(dmc.step), f_dm))
    return rows


def flops_report(
    steps: int, preset: str = "paper", compiled: bool = False, device: str = "cpu", dims: list[int] | None = None
) -> None:
    """The ``--flops`` table: per stage, seconds, FLOPs, GFLOP/s and % of the peak, fp32 / plain fp32 / bf16 (on
    a GPU: fp32 / bf16, the compile only for bf16, which is what ``paper`` runs there)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        peaks, how = gpu_peak(dev)
        ceilings = gpu_ceilings(dev)
        print(f"torch {torch.__version__}, {dev}; peak: {how}")
        print("measured ceiling, one 8192^2 product: " + ", ".join(f"{k} {v:,.0f}" for k, v in ceilings.items()))
        peak_of, ceiling_of = defaultdict(lambda: float("nan"), peaks), ceilings
    else:
        threads = torch.get_num_threads()
        peak, how = cpu_peak(threads)
        print(f"torch {torch.__version__}, {threads} thread(s); peak: {how}")
        ceiling = gemm_ceiling()
        print(f"measured ceiling: one [2048, 256] x [256, 256] fp32 product at {ceiling:.0f} GFLOP/s")
        peak_of, ceiling_of = defaultdict(lambda: peak), defaultdict(lambda: ceiling)
    if dims:
        grid = synthetic_grid(tuple(dims), 100_000)
    elif preset == "paper":
        grid = synthetic_grid((64, 32, 24), 100_000)
    else:
        grid = timing_grid(get_preset(preset).grid.resolution, 100_000, box=(1.0, 0.92, 0.92))
    print(f"preset {preset}, grid {tuple(grid.shape)}")
    cuda = dev.type == "cuda"
    runs = {"fp32": flops_stages("fp32", steps, grid, preset, compiled and not cuda, device)}
    if not cuda:  # the decoder's fast paths are CPU kernels
        pointops.ENABLED = False
        try:
            runs["fp32, plain decoder"] = flops_stages("fp32", steps, grid, preset)
        finally:
            pointops.ENABLED = True
    runs["bf16 autocast"] = flops_stages("bf16", steps, grid, preset, compiled, device)
    print("| stage | precision | seconds | GFLOP | GFLOP/s | against | % of peak | % of ceiling |")
    print("|---|---|---|---|---|---|---|---|")
    stages = list(dict.fromkeys(name for rows in runs.values() for name, *_ in rows))
    for stage in stages:
        for label, rows in runs.items():
            for sec, fl in [(sec, fl / 1e9) for name, sec, fl in rows if name == stage]:
                key = against(label, stage, cuda)
                rate = f"{fl / sec:.0f} | {key} | {100 * fl / sec / peak_of[key]:.1f} | "
                print(f"| {stage} | {label} | {sec:.4f} | {fl:.1f} | {rate}{100 * fl / sec / ceiling_of[key]:.1f} |")


def against(label: str, stage: str, cuda: bool) -> str:
    """Which peak a stage's rate is held against: bf16 under autocast; on a GPU the fp32 convolutions of the
    denoiser run on TF32 tensor cores (cuDNN's default, ``torch.backends.cudnn.allow_tf32``) while the point
    MLPs' fp32 matrix products do not (``torch.backends.cuda.matmul.allow_tf32`` is off by default)."""
    if not cuda:  # a CPU's peak here is its fp32 one
        return "fp32"
    if label.startswith("bf16"):
        return "bf16"
    convs = stage.startswith(("denoiser", "sampling"))
    return "tf32" if convs and torch.backends.cudnn.allow_tf32 else "fp32"


def timed(fn, steps: int, warmup: int = 2, repeats: int | None = None, cpu: bool = False) -> float:
    """Seconds per call: the mean over ``steps`` calls, or with ``repeats`` (or ``cpu``) the least of ``repeats``
    (default ``steps``) single calls; ``cpu`` measures the process's CPU time instead of the wall clock."""
    clock = time.process_time if cpu else time.perf_counter
    if repeats is not None or cpu:
        for _ in range(warmup):
            fn()
        best = float("inf")
        for _ in range(repeats or steps):
            t = clock()
            fn()
            best = min(best, clock() - t)
        return best
    return _timed_mean(fn, steps, warmup)


def _timed_mean(fn, steps: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    t = time.perf_counter()
    for _ in range(steps):
        fn()
    return (time.perf_counter() - t) / steps


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--presets", nargs="+", default=["tiny", "small", "paper"])
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--compile", action="store_true", help="also time the denoiser step after torch.compile")
    ap.add_argument("--grid", action="store_true", help="time the grid stage (mesh -> grid) instead")
    ap.add_argument(
        "--flops",
        nargs="?",
        const="paper",
        default=None,
        metavar="PRESET",
        help="FLOP/s per stage against the CPU's peak (default: the paper preset's networks)",
    )
    ap.add_argument("--device", default="cpu", help="with --flops: cpu or cuda")
    ap.add_argument("--dims", type=int, nargs=3, default=None, help="with --flops: the grid's size, e.g. 256 128 96")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[128, 256], help="with --grid")
    ap.add_argument("--faces", type=int, default=77_000, help="with --grid: faces kept of 81,920 (81920: closed)")
    ap.add_argument("--points", type=int, default=300_000, help="with --grid: near-surface training samples")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.grid:
        grid_times(a.resolutions, a.faces, a.points)
        return
    if a.flops:
        flops_report(a.steps, a.flops, a.compile, a.device, a.dims)
        return
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, device cpu")
    for name in a.presets:
        cfg = get_preset(name)
        r = cfg.grid.resolution
        dims = (r, r // 2, r * 3 // 8)  # a 2 : 1 : 0.75 box, like the canyon example
        grid = synthetic_grid(dims, 100_000)
        steps = 2 if name == "paper" else a.steps
        ae = AutoencoderTrainer(grid, replace(cfg.autoencoder, precision="fp32"))
        t_ours = timed(ae.step, steps)
        t_chunk = timed(lambda ae=ae: per_chunk_step(ae), steps)
        ae16 = AutoencoderTrainer(grid, replace(cfg.autoencoder, precision="bf16"))
        t_bf16 = timed(ae16.step, steps)
        print(
            f"[{name}] autoencoder, grid {dims}, {cfg.autoencoder.points_per_step:,} points: "
            f"ours {t_ours:.3f} s/step | per-chunk plane convs {t_chunk:.3f} s/step | ours in bf16 autocast "
            f"{t_bf16:.3f} s/step (the preset's 'auto' picks bf16: {bf16_is_fast('cpu')})"
        )
        h0 = ae.latent()
        dcfg = replace(cfg.diffusion, ema_decay=0.0, precision="fp32", compile=False)  # the same work for all
        dm = DiffusionTrainer(h0, dcfg)
        t_ours = timed(dm.step, steps)
        canvas = DiffusionTrainer(h0, dcfg)
        swap_convs(canvas.model)
        canvas.optimizer = torch.optim.AdamW(canvas.model.parameters(), lr=dcfg.lr)
        canvas.scheduler = torch.optim.lr_scheduler.LambdaLR(canvas.optimizer, lambda s: 1.0)
        t_canvas = timed(canvas.step, steps)
        cl = DiffusionTrainer(h0, dcfg)
        cl.model.to(memory_format=torch.channels_last)
        t_cl = timed(cl.step, steps)
        t_bf = timed(DiffusionTrainer(h0, replace(dcfg, precision="bf16")).step, steps)
        line = (
            f"[{name}] diffusion, latent {h0.resolution}, batch {cfg.diffusion.batch_size}, rollout "
            f"{dcfg.rollout}: ours {t_ours:.3f} s/step | canvas {t_canvas:.3f} s/step | channels-last "
            f"{t_cl:.3f} s/step | bf16 autocast {t_bf:.3f} s/step"
        )
        if a.compile:
            comp = DiffusionTrainer(h0, dcfg)
            comp.model.forward = torch.compile(comp.model.forward)
            t = time.perf_counter()
            comp.step()
            line += (
                f" | compiled {timed(comp.step, steps):.3f} s/step (after {time.perf_counter() - t:.0f} s to compile)"
            )
        print(line, flush=True)


if __name__ == "__main__":
    main()
