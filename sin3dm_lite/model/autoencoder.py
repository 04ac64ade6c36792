"""The triplane autoencoder: compress one shape's TSDF + colour grid into three 2D feature maps.

Sin3DM does not run diffusion on the 3D grid (too big) but on a *triplane*
latent. The encoder is deliberately tiny — one strided 3D convolution followed
by averaging the volume along each axis — so the latent keeps the grid's
spatial layout (a patch of the shape is a patch of the planes). The decoder
turns three plane features at a point into an SDF value and a colour; its
small per-plane ResNet blocks give each point some neighbourhood context.

Shapes (grid ``X × Y × Z``, latent ``X' = X/2`` etc.)::

    grid [1, 4, X, Y, Z]  (sdf / threshold, rgb·2−1)
      ├ Conv3d(1→4,  k4 s2 p1) on the sdf       → [1, 4, X', Y', Z']   geometry
      └ Conv3d(4→8,  k4 s2 p1) on sdf + rgb      → [1, 8, X', Y', Z']   texture
      concat → volume [1, 12, X', Y', Z']
      mean over z → xy [1, 12, X', Y'];  over y → xz;  over x → yz
      each plane: InstanceNorm → ×0.5 → tanh          (latent values in (-1, 1))

PBR variant (``AutoencoderConfig.pbr``, paper appendix): the grid carries 8
texture channels (``grid.PBR_CHANNELS``), so the texture convolution reads 9
channels, and the decoder gets two more heads on the same texture features:
metallic-roughness (2) and normal (3). The latent keeps its 12 channels.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..app.device import autocast
from ..data.config import AutoencoderConfig
from ..data.grid import ShapeGrid
from ..errors import Sin3DMInputError
from ..kernels.bf16ops import mlp_bf16_ok, skip_mlp_bf16
from ..kernels.pointops import Workspace, mlp_fast_ok, skip_mlp
from .training import Trainer
from .triplane import PLANES, Triplane


# --------------------------------------------------------------------------- encoder
class TriplaneEncoder(nn.Module):
    """Conv3D (k4, s2) + axis mean-pooling + InstanceNorm + ×0.5 + tanh (docs/paper-notes.md "Triplane autoencoder")."""

    def __init__(self, cfg: AutoencoderConfig, color_channels: int = 3):
        super().__init__()
        # replicate padding: zeros would read as "surface" (sdf = 0) all around the box
        self.geo = nn.Conv3d(1, cfg.geo_channels, kernel_size=4, stride=2, padding=1, padding_mode="replicate")
        self.tex = nn.Conv3d(
            1 + color_channels, cfg.tex_channels, kernel_size=4, stride=2, padding=1, padding_mode="replicate"
        )

    def volume(self, grid: torch.Tensor) -> torch.Tensor:
        """``[B, 1+K, X, Y, Z]`` → the pre-pooling feature volume ``[B, 12, X/2, Y/2, Z/2]``."""
        return torch.cat([self.geo(grid[:, :1]), self.tex(grid)], dim=1)

    @staticmethod
    def squash(plane: torch.Tensor) -> torch.Tensor:
        """InstanceNorm (no affine) → ×0.5 → tanh: keeps latent values well inside (-1, 1)."""
        return torch.tanh(0.5 * F.instance_norm(plane))

    def forward(self, grid: torch.Tensor) -> Triplane:
        """The three planes: :meth:`volume` averaged along each axis, computed without the volume.

        A plane is the mean of a convolution along one axis, and the mean of a
        convolution is a convolution of means: average the padded grid along
        that axis at each of the kernel's 4 offsets (every second voxel), stack
        the 4 averages as channels, and convolve in 2D with the kernel's matching
        slices. Same planes (to rounding), a fraction of the work.
        """
        planes = []
        for axis, taps in zip((4, 3, 2), self.taps(grid)):  # xy: mean over z, xz: over y, yz: over x
            f = [_tap_conv(self.geo, taps[:, :1], axis), _tap_conv(self.tex, taps, axis)]
            planes.append(self.squash(torch.cat(f, dim=1)))
        return Triplane(*planes)

    def taps(self, grid: torch.Tensor) -> list[torch.Tensor]:
        """Per plane (xy, xz, yz), the padded grid averaged along its axis at each of the kernel's offsets,
        ``[B, C, k, a, b]``. A fit feeds the same grid at every step, so the last grid's are kept (checked by
        identity and version counter)."""
        cached = getattr(self, "_taps", None)
        if cached is not None and cached[0]() is grid and cached[1] == grid._version:
            return cached[2]
        k, s, p = self.tex.kernel_size[0], self.tex.stride[0], self.tex.padding[0]  # 4, 2, 1 (geo's too)
        padded = F.pad(grid, (p,) * 6, mode="replicate")
        out = []
        for axis in (4, 3, 2):
            x = padded.movedim(axis, -1)  # [B, C, a, b, n + 2p]: the averaged axis last
            n_out = (x.shape[-1] - k) // s + 1
            out.append(torch.stack([x[..., d : d + s * (n_out - 1) + 1 : s].mean(-1) for d in range(k)], dim=2))
        if not grid.requires_grad:  # a constant: keep it (a grid that needs gradients would keep its graph alive)
            self._taps = (weakref.ref(grid), grid._version, out)
        return out

    def __getstate__(self) -> dict:  # pickled (a worker, torch.save of the module) without the cache
        state = self.__dict__.copy()
        state.pop("_taps", None)
        return state


def _tap_conv(conv: nn.Conv3d, taps: torch.Tensor, axis: int) -> torch.Tensor:
    """``conv``'s output averaged along ``axis``, from the input's averages ``taps`` ``[B, C, k, a, b]``: a 2D
    convolution whose input channels are (channel, offset) pairs and whose kernel is ``conv``'s, the averaged axis
    moved next to the channels."""
    b, c, k = taps.shape[:3]
    weight = conv.weight.movedim(axis, 2)  # [O, C, k (the averaged axis), k, k]
    return F.conv2d(
        taps.reshape(b, c * k, *taps.shape[3:]), weight.reshape(len(weight), c * k, k, k), conv.bias, conv.stride[0]
    )


# --------------------------------------------------------------------------- decoder
class PlaneResBlock(nn.Module):
    """2D ResNet block applied to one plane: Conv5×5+IN+SiLU → Conv5×5 (zero-init), plus a 1×1 shortcut."""

    def __init__(self, c_in: int, c_out: int, k: int = 5):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, k, padding=k // 2)
        self.conv2 = nn.Conv2d(c_out, c_out, k, padding=k // 2)
        self.skip = nn.Conv2d(c_in, c_out, 1)
        nn.init.zeros_(self.conv2.weight)
        nn.init.zeros_(self.conv2.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.skip(x) + self.conv2(F.silu(F.instance_norm(self.conv1(x))))


class SkipMLP(nn.Module):
    """DeepSDF-style MLP: 3 × (Linear+ReLU), concatenate the input, 2 × (Linear+ReLU), Linear → out."""

    def __init__(self, c_in: int, hidden: int, c_out: int):
        super().__init__()
        self.a = nn.Sequential(
            nn.Linear(c_in, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
        )
        self.b = nn.Sequential(nn.Linear(hidden + c_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())
        self.out = nn.Linear(hidden, c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if mlp_fast_ok(x, self):  # the same layers, chunk by chunk (kernels/pointops.py)
            if getattr(self, "_workspace", None) is None:
                self._workspace = Workspace()
            return skip_mlp(x, self.a, self.b, self.out, self._workspace if self.training else None)
        if mlp_bf16_ok(x, self):  # under bf16 autocast: the same products chunk by chunk (kernels/bf16ops.py)
            return skip_mlp_bf16(x, self.a, self.b, self.out)
        return self.out(self.b(torch.cat([self.a(x), x], dim=-1)))

    def train(self, mode: bool = True) -> SkipMLP:
        """Also drops the fast path's kept buffers when leaving training (``eval()``): they are a step's size."""
        if not mode:
            self._workspace = None
        return super().train(mode)

    def __getstate__(self) -> dict:  # pickled and deep-copied without the kept buffers
        state = self.__dict__.copy()
        state.pop("_workspace", None)
        return state


@dataclass
class PreparedPlanes:
    """Decoder features of one batch of triplanes: 64-channel geometry and texture planes."""

    geo: Triplane
    tex: Triplane | None


#: texture channels of the PBR variant and the heads that predict them: colour (3), metallic-roughness (2), normal (3)
PBR_HEADS = {"tex_mlp": 3, "mr_mlp": 2, "normal_mlp": 3}


class TriplaneDecoder(nn.Module):
    """Triplane → (SDF, colour) at any 3D point.

    Geometry channels (0..3) and texture channels (4..11) are decoded
    separately: each group gets one :class:`PlaneResBlock` per plane (no mixing
    between planes), a bilinear lookup at the point's three projections, the
    sum of the three features, and a :class:`SkipMLP` head. The SDF head
    predicts ``sdf / threshold`` so its targets are O(1); the colour head ends
    in a sigmoid. With ``cfg.pbr`` two more heads, ``mr_mlp`` (metallic,
    roughness) and ``normal_mlp``, read the same texture features, and
    ``query_color`` returns all 8 channels in ``grid.PBR_CHANNELS`` order.

    Use it in two steps so the plane convolutions run once per triplane::

        prepared = decoder.prepare(triplane)
        sdf, rgb = decoder.query(prepared, points_in_box_coords)   # [B, N], [B, N, 3]
    """

    def __init__(self, cfg: AutoencoderConfig, threshold: float, color_channels: int = 3):
        super().__init__()
        self.geo_channels = cfg.geo_channels
        c, k = cfg.decoder_channels, cfg.decoder_kernel
        self.geo_blocks = nn.ModuleList(PlaneResBlock(cfg.geo_channels, c, k) for _ in PLANES)
        self.tex_blocks = nn.ModuleList(PlaneResBlock(cfg.tex_channels, c, k) for _ in PLANES)
        self.geo_mlp = SkipMLP(c, cfg.mlp_hidden, 1)
        self.color_channels = color_channels
        if cfg.pbr:
            if color_channels != sum(PBR_HEADS.values()):
                raise ValueError(
                    f"the PBR decoder predicts {sum(PBR_HEADS.values())} texture channels, not {color_channels}"
                )
            self.tex_mlp = SkipMLP(c, cfg.mlp_hidden, PBR_HEADS["tex_mlp"])
            self.mr_mlp = SkipMLP(c, cfg.mlp_hidden, PBR_HEADS["mr_mlp"])
            self.normal_mlp = SkipMLP(c, cfg.mlp_hidden, PBR_HEADS["normal_mlp"])
            self.heads = [self.tex_mlp, self.mr_mlp, self.normal_mlp]
        else:
            self.tex_mlp = SkipMLP(c, cfg.mlp_hidden, color_channels)
            self.heads = [self.tex_mlp]
        self.register_buffer("threshold", torch.tensor(float(threshold)))

    def prepare(self, tp: Triplane, texture: bool = True) -> PreparedPlanes:
        """The plane convolutions of ``tp`` (``texture=False``: the geometry's only; ``query_color`` then fails)."""
        g = self.geo_channels
        geo = [blk(p[:, :g]) for blk, p in zip(self.geo_blocks, tp.planes)]
        tex = Triplane(*(blk(p[:, g:]) for blk, p in zip(self.tex_blocks, tp.planes))) if texture else None
        return PreparedPlanes(Triplane(*geo), tex)

    def query_sdf(self, prep: PreparedPlanes, points: torch.Tensor) -> torch.Tensor:
        """SDF in normalised units (negative inside), ``[B, N]``."""
        f = prep.geo.lookup(points, reduce="sum")  # [B, N, 64]: the three plane features added
        return self.geo_mlp(f)[..., 0] * self.threshold

    def query_color(self, prep: PreparedPlanes, points: torch.Tensor, logits: bool = False) -> torch.Tensor:
        """Colour (and with PBR metallic, roughness, normal · ½ + ½) in [0, 1], ``[B, N, K]``
        (``logits``: the heads' outputs before the sigmoid)."""
        f = prep.tex.lookup(points, reduce="sum")
        out = torch.cat([head(f) for head in self.heads], dim=-1)
        return out if logits else torch.sigmoid(out)

    def query(self, prep: PreparedPlanes, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.query_sdf(prep, points), self.query_color(prep, points)

    def param_groups(self) -> tuple[list[nn.Parameter], list[nn.Parameter]]:
        geo = [*self.geo_blocks.parameters(), *self.geo_mlp.parameters()]
        tex = [*self.tex_blocks.parameters(), *(p for head in self.heads for p in head.parameters())]
        return geo, tex


# --------------------------------------------------------------------------- the model
def grid_tensor(grid: ShapeGrid, device: torch.device | str = "cpu") -> torch.Tensor:
    """``ShapeGrid`` → the encoder's input ``[1, 1+K, X, Y, Z]``: sdf/threshold and colour·2−1."""
    sdf = torch.from_numpy(grid.sdf / grid.threshold).float()[None]
    col = torch.from_numpy(grid.color).float().permute(3, 0, 1, 2) * 2 - 1
    return torch.cat([sdf, col])[None].to(device)


class TriplaneAutoencoder(nn.Module):
    """Encoder (or, with ``use_encoder=False``, directly optimised planes) + decoder for one shape."""

    def __init__(
        self, cfg: AutoencoderConfig, grid_shape: tuple[int, int, int], threshold: float, color_channels: int = 3
    ):
        super().__init__()
        self.cfg = cfg
        self.grid_shape = tuple(int(s) for s in grid_shape)
        x, y, z = (s // 2 for s in self.grid_shape)
        sizes = dict(zip(("xy", "xz", "yz"), ((x, y), (x, z), (y, z))))
        if cfg.use_encoder:
            self.encoder = TriplaneEncoder(cfg, color_channels)
        else:  # auto-decoder: the raw planes are parameters, squashed like the encoder's output
            # geometry and texture channels apart, so each trains at its own learning rate
            self.raw_geo, self.raw_tex = (
                nn.ParameterDict({n: nn.Parameter(0.1 * torch.randn(1, c, *ab)) for n, ab in sizes.items()})
                for c in (cfg.geo_channels, cfg.tex_channels)
            )
        self.decoder = TriplaneDecoder(cfg, threshold, color_channels)

    def encode(self, grid_t: torch.Tensor | None = None) -> Triplane:
        """The latent triplane ``h0`` (batch 1, values in (-1, 1))."""
        if self.cfg.use_encoder:
            return self.encoder(grid_t)
        sq = TriplaneEncoder.squash
        return Triplane(*(sq(torch.cat([self.raw_geo[n], self.raw_tex[n]], 1)) for n in ("xy", "xz", "yz")))

    def hold_color(self, color: np.ndarray) -> None:
        """Make the texture half decode ``color`` everywhere and stay fixed: for a shape of one colour.

        The fit then spends its steps on the geometry alone. The texture channels of the latent become zero (a zero
        convolution, normalised, is zero), and the colour head outputs its bias, the colour's logit, whatever the
        features; no texture parameter needs a gradient."""
        if self.cfg.pbr:
            raise ValueError("hold_color is for RGB shapes: a PBR shape's normals vary over its surface")
        head = self.decoder.tex_mlp.out
        latent = self.encoder.tex.parameters() if self.cfg.use_encoder else self.raw_tex.parameters()
        with torch.no_grad():
            for p in self.param_groups()[1]:
                p.requires_grad_(False)
            for p in (*latent, head.weight):
                p.zero_()
            head.bias.copy_(torch.logit(torch.as_tensor(color, dtype=head.bias.dtype), eps=1e-4))

    def param_groups(self) -> tuple[list[nn.Parameter], list[nn.Parameter]]:
        """Geometry and texture parameters (they get different learning rates)."""
        geo, tex = self.decoder.param_groups()
        if self.cfg.use_encoder:
            geo += list(self.encoder.geo.parameters())
            tex += list(self.encoder.tex.parameters())
        else:
            geo += list(self.raw_geo.parameters())
            tex += list(self.raw_tex.parameters())
        return geo, tex


# --------------------------------------------------------------------------- loss
#: the sigmoid's input is kept within ± this: beyond it the colour lies within 1/3000 of 0 or 1 (less than an 8-bit
#: step), the sigmoid is nearly flat, and in float32 soon exactly flat, so the L1 colour loss passes no gradient back
#: and a channel pushed there stays (a texture of pure colours had its whole colour head stuck on one colour)
LOGIT_BOUND = 8.0


def logit_bound(logit: torch.Tensor) -> torch.Tensor:
    """How far the colour heads' outputs lie beyond ±:data:`LOGIT_BOUND` (mean): zero wherever the paper's L1 colour
    loss still has a slope, a pull back where it has none."""
    return F.relu(logit.abs() - LOGIT_BOUND).mean()


def sdf_loss(
    pred: torch.Tensor, gt: torch.Tensor, threshold: float, near_w: float = 1.5, far_w: float = 0.5
) -> torch.Tensor:
    """Weighted L1 on the truncated SDF.

    An error that moves the prediction towards or across the surface
    (``|pred| < |gt|`` or a sign flip) costs ``near_w``; one that pushes it
    further away costs ``far_w``: surface-crossing errors create false
    geometry, so they matter more. Beyond the truncation band any value of the
    right sign is correct.
    """
    beyond = (gt.abs() >= threshold * 0.999) & (pred * gt > 0) & (pred.abs() > gt.abs())
    pred = torch.where(beyond, gt, pred)
    towards = (pred * gt <= 0) | (pred.abs() < gt.abs())
    w = torch.where(towards, near_w, far_w)
    return (w * (pred - gt).abs()).mean() / threshold


class PointSampler:
    """Draws training batches: ``grid_fraction`` random voxels, the rest near-surface points."""

    def __init__(self, grid: ShapeGrid, device: torch.device):
        self.device = device
        self.threshold = grid.threshold
        self.vox = torch.from_numpy(grid.to_box(grid.voxel_centers().reshape(-1, 3))).to(device)
        self.vox_sdf = torch.from_numpy(grid.sdf.reshape(-1)).float().to(device)
        self.vox_col = torch.from_numpy(grid.color.reshape(-1, grid.color.shape[-1])).float().to(device)
        if len(grid.points):
            self.pts = torch.from_numpy(grid.to_box(grid.points)).to(device)
            self.pts_sdf = torch.from_numpy(grid.point_sdf).float().to(device)
            self.pts_col = torch.from_numpy(grid.point_color).float().to(device)
        else:  # no surface samples: fall back to voxels inside the band
            band = self.vox_sdf.abs() < self.threshold
            self.pts, self.pts_sdf, self.pts_col = self.vox[band], self.vox_sdf[band], self.vox_col[band]

    def __call__(self, n: int, fraction: float, gen: torch.Generator):
        n_vox = int(round(n * fraction))
        iv = torch.randint(len(self.vox), (n_vox,), generator=gen).to(self.device)
        ip = torch.randint(len(self.pts), (n - n_vox,), generator=gen).to(self.device)
        p = torch.cat([self.vox[iv], self.pts[ip]])
        s = torch.cat([self.vox_sdf[iv], self.pts_sdf[ip]])
        c = torch.cat([self.vox_col[iv], self.pts_col[ip]])
        return p, s, c


# --------------------------------------------------------------------------- training
class AutoencoderTrainer(Trainer):
    """Fits a :class:`TriplaneAutoencoder` to one :class:`ShapeGrid`, resumable step by step (:class:`Trainer`).

    AdamW with a geometry and a texture learning rate, both decayed exponentially to ``lr_final_factor`` of their
    start over ``cfg.steps``. The point batches are drawn on the CPU (the same batches on every device).
    """

    kind = "autoencoder"
    loss_names = ("loss", "sdf", "color")

    def __init__(self, grid: ShapeGrid, cfg: AutoencoderConfig, device=None, seed: int = 0):
        super().__init__(cfg, device, seed, generator_device="cpu")
        if cfg.pbr != grid.has_pbr:
            raise Sin3DMInputError(
                f"the grid has {grid.color.shape[-1]} texture channels but the config says pbr={cfg.pbr}; "
                f"use AutoencoderConfig(pbr={grid.has_pbr}) (or rebuild the grid with mesh_to_grid(..., pbr={cfg.pbr}))"
            )
        if cfg.pbr:  # the history also keeps the two material losses
            self.loss_names = (*self.loss_names, "material", "normal")
            self.history.update(material=[], normal=[])
        self.grid = grid
        self.model = self.init_model(lambda: TriplaneAutoencoder(cfg, grid.shape, grid.threshold, grid.color.shape[-1]))
        self.grid_t = grid_tensor(grid, self.device) if cfg.use_encoder else None  # the auto-decoder never reads it
        self.sampler = PointSampler(grid, self.device)
        #: the shape's one colour (RGB shapes only), which the texture half then decodes without training
        self.single_color = None if cfg.pbr else grid.single_color()
        if self.single_color is not None:
            self.model.hold_color(self.single_color)
        geo, tex = self.model.param_groups()  # held parameters stay in their group: without a gradient, never moved
        self.optimizer = self.adamw([{"params": geo, "lr": cfg.lr_geo}, {"params": tex, "lr": cfg.lr_tex}])
        gamma = cfg.lr_final_factor ** (1.0 / max(1, cfg.steps))
        self.scheduler = torch.optim.lr_scheduler.ExponentialLR(self.optimizer, gamma)

    def losses(self) -> dict[str, torch.Tensor]:
        """SDF loss on a batch of points plus the L1 colour loss on those within the truncation band (and
        :func:`logit_bound`, which keeps the colour's sigmoid where it has a slope).

        PBR: binary cross-entropy on metallic-roughness (``material``; on the
        heads' logits) and L1 on the normal in its [0, 1] encoding (``normal``)
        at the same band points, each weighted 1 like the colour (the paper
        gives no weights). Cross-entropy, not L1, for metallic (mostly 0 with
        metal islands): L1 drives the logits deep into the sigmoid's flat end,
        where no gradient passes; the cross-entropy's, sigmoid(logit) - target,
        does not vanish.
        """
        cfg = self.cfg
        p, s_gt, c_gt = self.sampler(cfg.points_per_step, cfg.grid_fraction, self.generator)
        held = self.single_color is not None  # one colour, decoded exactly: nothing for the texture half to learn
        with autocast(self.device, cfg.precision):  # the network in bf16 where that is fast; losses in fp32
            prep = self.model.decoder.prepare(self.model.encode(self.grid_t), texture=not held)
            s = self.model.decoder.query_sdf(prep, p[None])[0].float()
        l_sdf = sdf_loss(s, s_gt, self.grid.threshold, cfg.near_weight, cfg.far_weight)
        zero = torch.zeros((), device=self.device)
        if held:
            return {"loss": l_sdf, "sdf": l_sdf, "color": zero}
        band = s_gt.abs() < self.grid.threshold  # colour is only defined near the surface
        if cfg.color_points:  # the first of them (the points come in random order): a random subset
            band &= band.cumsum(0) <= cfg.color_points
        with autocast(self.device, cfg.precision):
            logit = self.model.decoder.query_color(prep, p[band][None], logits=True)[0].float()
        l_col = l_mat = l_nrm = bound = zero
        if band.any():
            c, gt = torch.sigmoid(logit), c_gt[band]
            l_col = (c[:, :3] - gt[:, :3]).abs().mean()
            bound = logit_bound(logit[:, :3])  # the colour's only: on the normal's channels it cost them accuracy
            if cfg.pbr:
                l_nrm = (c[:, 5:8] - gt[:, 5:8]).abs().mean()
                l_mat = F.binary_cross_entropy_with_logits(logit[:, 3:5], gt[:, 3:5])
        if not cfg.pbr:
            return {"loss": l_sdf + l_col + bound, "sdf": l_sdf, "color": l_col}
        loss = l_sdf + l_col + l_mat + l_nrm + bound
        return {"loss": loss, "sdf": l_sdf, "color": l_col, "material": l_mat, "normal": l_nrm}

    @torch.no_grad()
    def latent(self) -> Triplane:
        """The fitted latent ``h0`` (batch 1) that the diffusion model learns from."""
        self.model.eval()
        return self.model.encode(self.grid_t).detach()


def fit_autoencoder(grid: ShapeGrid, cfg: AutoencoderConfig, device=None, seed: int = 0, progress: bool = True):
    """Fit the autoencoder to one shape. Returns ``(model, h0, history)``."""
    tr = AutoencoderTrainer(grid, cfg, device, seed)
    tr.run(progress=progress)
    return tr.model, tr.latent(), tr.history
