"""What several test files share: grids, analytic decoders, tiny configs, small helpers.

Fixtures are found by pytest; the plain helpers (classes subclassed at module
level, functions called with other arguments) are imported with
``from .conftest import ...`` (``tests`` is a package for that).
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
import matplotlib  # noqa: E402

matplotlib.use("Agg")  # before any test module imports pyplot

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
from torch import nn  # noqa: E402

from sin3dm_lite.data.config import AutoencoderConfig, Config, DiffusionConfig  # noqa: E402
from sin3dm_lite.data.grid import ShapeGrid, mesh_to_grid  # noqa: E402
from sin3dm_lite.data.mesh import Material, Normalization, TexturedMesh  # noqa: E402
from sin3dm_lite.model.triplane import Triplane  # noqa: E402
from sin3dm_lite.presets import get_preset  # noqa: E402

# a non-cubic box, symmetric like ShapeGrid's (±n_axis / n_max): 24 × 32 × 20 voxels at resolution 32
AABB = np.array([-0.75, -1.0, -0.625, 0.75, 1.0, 0.625])
#: `sample` flags for tests that need *a* mesh, not a good one: 3 DDIM steps, a 32-voxel decode, small files
CHEAP_SAMPLE = ["--steps", "3", "--mesh-resolution", "32", "--faces", "500", "--texture-size", "64", "--no-pictures"]
LATENT_RES = (8, 8, 8)  # the diffusion tests' latent


# --------------------------------------------------------------------------- order
def pytest_collection_modifyitems(session, config, items):
    """The notebooks (tens of seconds each) first, then the tests in their usual order.

    pytest-xdist hands the items out in this order, in chunks; with the notebooks last, a run could end with one
    worker idle while the other ran a notebook, with them first it ends on short tests. A stable sort: each group
    keeps its order, so the tests of a module stay together (and share their module's fixtures on one worker).
    """
    items.sort(key=lambda item: not item.nodeid.startswith("notebooks/"))


# --------------------------------------------------------------------------- meshes and grids
def textured(m: trimesh.Trimesh, name="m", **kw) -> TexturedMesh:
    """A trimesh as a one-material ``TexturedMesh`` (white base colour); ``kw`` e.g. ``vertex_colors``."""
    return TexturedMesh(
        np.asarray(m.vertices, float),
        np.asarray(m.faces, np.int64),
        np.zeros(len(m.faces), np.int64),
        [Material()],
        name=name,
        **kw,
    )


def make_sphere_grid(shape=(16, 12, 20), radius=0.45, threshold_voxels=3.0, n_points=500) -> ShapeGrid:
    """A sphere's TSDF on a non-cubic grid, coloured by position (red grows with x), built analytically."""
    n_max = max(shape)
    half = np.array(shape) / n_max
    aabb = np.concatenate([-half, half]).astype(np.float32)
    voxel = 2.0 / n_max
    thr = threshold_voxels * voxel
    g = ShapeGrid(np.zeros(shape, np.float32), np.zeros((*shape, 3), np.float32), aabb, thr, Normalization.identity())
    c = g.voxel_centers()
    sdf = np.linalg.norm(c, axis=-1) - radius
    g.sdf = np.clip(sdf, -thr, thr).astype(np.float32)
    col = np.clip((c + 1) / 2, 0, 1).astype(np.float32)
    g.color = np.where((np.abs(sdf) < thr)[..., None], col, 0.0).astype(np.float32)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = radius + rng.normal(scale=voxel, size=(n_points, 1))
    g.points = (d * r).astype(np.float32)
    g.point_sdf = np.clip(r[:, 0] - radius, -thr, thr).astype(np.float32)
    g.point_color = np.clip((g.points + 1) / 2, 0, 1)
    g.name = "sphere"
    return g


@pytest.fixture(scope="session")
def sphere_grid() -> ShapeGrid:
    """:func:`make_sphere_grid` with its defaults: 16 × 12 × 20 voxels, truncated at 3 voxels."""
    return make_sphere_grid()


@pytest.fixture(scope="session")
def box_grid() -> ShapeGrid:
    """A 1 × 0.6 × 0.4 box coloured by position, gridded at 32 with 20,000 surface points (``mesh_to_grid``)."""
    m = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    v = np.asarray(m.vertices, float)
    vc = ((v - v.min(0)) / np.ptp(v, 0)).astype(np.float32)  # colour varies with position
    return mesh_to_grid(
        textured(m, vertex_colors=vc), 32, n_surface_points=20_000, near_surface_sigma=0.03, progress=False
    )


# --------------------------------------------------------------------------- triplanes and decoders
def zero_triplane(batch=1, res=(12, 16, 10)) -> Triplane:
    """Four channels of zeros; with :class:`SphereDecoder` it decodes to the plain sphere."""
    x, y, z = res
    return Triplane(torch.zeros(batch, 4, x, y), torch.zeros(batch, 4, x, z), torch.zeros(batch, 4, y, z))


class SphereDecoder(nn.Module):
    """Sphere of radius 0.5 (normalised units) centred in the box it was made for; colour = (p_box + 1) / 2.

    The SDF is a function of *box* coordinates (like a real decoder), so the
    same decoder with a larger box gives a stretched shape. A triplane's mean
    (zero for :func:`zero_triplane`) is added to the SDF.
    """

    def __init__(self, aabb=AABB, radius=0.5):
        super().__init__()
        aabb = np.asarray(aabb, np.float32)
        self.register_buffer("half_extent", torch.tensor((aabb[3:] - aabb[:3]) / 2))
        self.register_buffer("middle", torch.tensor((aabb[3:] + aabb[:3]) / 2))
        self.weight = nn.Parameter(torch.zeros(1))  # gives the module a device
        self.radius = radius
        self.prepare_calls = 0
        self.query_calls = 0

    def prepare(self, tp: Triplane):
        self.prepare_calls += 1
        return {"offset": tp.xy.mean(dim=(1, 2, 3)) + self.weight}  # zero for a zero triplane

    def query(self, prepared, points):
        self.query_calls += 1
        p = points * self.half_extent + self.middle
        sdf = p.norm(dim=-1) - self.radius + prepared["offset"][:, None]
        return sdf, (points + 1) / 2


@pytest.fixture(scope="session")
def h0() -> Triplane:
    """A random latent (4 channels, :data:`LATENT_RES`, tanh range) for the diffusion tests."""
    g = torch.Generator().manual_seed(1)
    return Triplane.randn(1, 4, LATENT_RES, generator=g).map(torch.tanh)


# --------------------------------------------------------------------------- tiny configs
def tiny_ae_cfg(**kw) -> AutoencoderConfig:
    """An autoencoder small enough to fit :func:`box_grid` in seconds (120 steps of 2,048 points)."""
    base = dict(decoder_channels=16, mlp_hidden=32, steps=120, points_per_step=2048)
    base.update(kw)
    return AutoencoderConfig(**base)


def tiny_diffusion_cfg(**kw) -> DiffusionConfig:
    """A denoiser without down-sampling, 16 channels, 60 steps of batch 4, no EMA."""
    base = dict(base_channels=16, n_resblocks=2, downsample=False, steps=60, batch_size=4, lr=2e-3, ema_decay=0.0)
    return DiffusionConfig(**{**base, **kw})


def micro_config() -> Config:
    """``tiny`` made smaller still: 24 voxels, 30 autoencoder and 30 denoiser steps, a checkpoint every 10."""
    return get_preset("tiny").updated(
        **{
            "grid.resolution": 24,
            "grid.n_surface_points": 5000,
            "autoencoder.steps": 30,
            "autoencoder.points_per_step": 1024,
            "diffusion.steps": 30,
            "checkpoint_every": 10,
            "sampling.mesh_resolution": 32,
            "sampling.faces": 2000,
            "sampling.texture_size": 128,
        }
    )


@pytest.fixture(scope="session")
def micro_fit(tmp_path_factory):
    """The wall example fitted at :func:`micro_config` (seed 0), once per session: ``(model, run folder)``.

    Shared by the tests that need *a* fitted model (pipeline, control, widgets, render, runs, the run-folder
    lock); under pytest-xdist each worker fits its own. Both are read-only: a test that writes into a run folder
    copies it first, and a module that uses the model takes a :func:`micro_model` of its own (the model keeps
    caches, e.g. of the input's reconstruction, which one module's calls would fill for the next).
    """
    import warnings

    from sin3dm_lite.pipeline import Sin3DM

    run = tmp_path_factory.mktemp("micro") / "wall"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a micro fit reconstructs poorly
        model = Sin3DM.fit("wall", preset=micro_config(), out=run, progress=False)
    return model, run


def micro_model(micro_fit):
    """A copy of :func:`micro_fit`'s model, as ``Sin3DM.fit`` returned it, for one module."""
    import copy

    return copy.deepcopy(micro_fit[0])


# --------------------------------------------------------------------------- receptive fields
def rf_square(n=33, width=9, zero_corner=True) -> np.ndarray:
    """An ``n × n`` receptive-field map: 1 at the centre, 0.1 in a ``width`` square, 1e-3 elsewhere
    (and 0 in one corner with ``zero_corner``, as a measured map can have)."""
    c, h = n // 2, width // 2
    rf = np.full((n, n), 1e-3)
    rf[c - h : c + h + 1, c - h : c + h + 1] = 0.1
    rf[c, c] = 1.0
    if zero_corner:
        rf[0, 0] = 0.0
    return rf


# --------------------------------------------------------------------------- a folder of samples to write into
@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """The shipped model as a run folder, and one sample of it (cheap settings)."""
    import shutil

    from sin3dm_lite.app.pretrained import pretrained_path
    from sin3dm_lite.cli import main

    root = tmp_path_factory.mktemp("folders")
    shutil.copytree(pretrained_path(), root / "run")
    cheap = [*CHEAP_SAMPLE, "--workers", "0"]
    assert main(["sample", str(root / "run"), "--out", str(root / "samples"), "-n", "1", *cheap]) == 0
    return root


@pytest.fixture
def work(template, tmp_path, monkeypatch):
    """A copy of :func:`template` (new times: the copied samples must stay ours), the working folder."""
    import shutil

    ws = tmp_path / "ws"
    shutil.copytree(template, ws)
    monkeypatch.chdir(ws)
    return ws
