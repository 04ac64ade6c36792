"""The triplane latent: three axis-aligned 2D feature maps instead of a 3D grid.

Sin3DM compresses the shape's ``X × Y × Z`` grid into three planes
``xy [C, X', Y']``, ``xz [C, X', Z']`` and ``yz [C, Y', Z']`` (half the grid's
resolution). A 3D point's feature is read from each plane by bilinear
interpolation at its projection, and a decoder turns the three features into
an SDF value and a colour. The diffusion model then works on these 2D maps,
which is far cheaper than 3D.

Conventions used everywhere in the package:

* Tensors always carry a batch dimension: ``xy`` is ``[B, C, X, Y]``.
* Points are given in *box coordinates* in ``[-1, 1]^3`` (the shape's
  bounding box ``aabb`` mapped to the unit cube), and planes are cell-centred:
  texel ``i`` of an axis with ``n`` texels sits at ``-1 + (2i + 1) / n``
  (``align_corners=False`` in PyTorch terms). Outside the box, lookups repeat
  the border texel.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..kernels.pointops import lookup_fast_ok, lookup_sum

PLANES = ("xy", "xz", "yz")
#: which point axes (0 = x, 1 = y, 2 = z) index each plane's rows and columns
PLANE_AXES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


@dataclass
class Triplane:
    """Three feature planes sharing channels and batch: ``xy [B,C,X,Y]``, ``xz [B,C,X,Z]``, ``yz [B,C,Y,Z]``."""

    xy: torch.Tensor
    xz: torch.Tensor
    yz: torch.Tensor

    def __post_init__(self) -> None:
        b, c, x, y = self.xy.shape
        b2, c2, x2, z = self.xz.shape
        b3, c3, y3, z3 = self.yz.shape
        if not (b == b2 == b3 and c == c2 == c3 and x == x2 and y == y3 and z == z3):
            raise ValueError(
                f"inconsistent triplane shapes xy{tuple(self.xy.shape)} xz{tuple(self.xz.shape)} yz{tuple(self.yz.shape)}"
            )

    # ---------------------------------------------------------------- basics
    @property
    def planes(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return (self.xy, self.xz, self.yz)

    @property
    def batch(self) -> int:
        return self.xy.shape[0]

    @property
    def channels(self) -> int:
        return self.xy.shape[1]

    @property
    def resolution(self) -> tuple[int, int, int]:
        """Spatial size ``(X, Y, Z)``."""
        return (self.xy.shape[2], self.xy.shape[3], self.xz.shape[3])

    @property
    def device(self) -> torch.device:
        return self.xy.device

    def map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> Triplane:
        """Apply ``fn`` to each plane."""
        return Triplane(fn(self.xy), fn(self.xz), fn(self.yz))

    def zip_map(self, other: Triplane, fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]) -> Triplane:
        return Triplane(fn(self.xy, other.xy), fn(self.xz, other.xz), fn(self.yz, other.yz))

    def to(self, *args, **kwargs) -> Triplane:
        return self.map(lambda p: p.to(*args, **kwargs))

    def detach(self) -> Triplane:
        return self.map(torch.Tensor.detach)

    def clone(self) -> Triplane:
        return self.map(torch.Tensor.clone)

    def cpu(self) -> Triplane:
        return self.map(torch.Tensor.cpu)

    def __getitem__(self, index) -> Triplane:
        """Batch indexing that keeps the batch dimension: ``tp[0]`` is a batch of one."""
        if isinstance(index, int):
            index = slice(index, index + 1) if index != -1 else slice(-1, None)
        return self.map(lambda p: p[index])

    def repeat(self, n: int) -> Triplane:
        return self.map(lambda p: p.repeat(n, 1, 1, 1))

    def resized(self, resolution: tuple[int, int, int]) -> Triplane:
        """Bilinear resampling of every plane to the spatial size ``(X, Y, Z)`` (texel centres kept in place)."""
        x, y, z = resolution
        sizes = {"xy": (x, y), "xz": (x, z), "yz": (y, z)}
        return Triplane(
            *(
                F.interpolate(p, size=sizes[name], mode="bilinear", align_corners=False)
                if p.shape[-2:] != sizes[name]
                else p
                for name, p in zip(PLANES, self.planes)
            )
        )

    def __add__(self, other):
        return self.zip_map(other, torch.add) if isinstance(other, Triplane) else self.map(lambda p: p + other)

    def __sub__(self, other):
        return self.zip_map(other, torch.sub) if isinstance(other, Triplane) else self.map(lambda p: p - other)

    def __mul__(self, other):
        return self.zip_map(other, torch.mul) if isinstance(other, Triplane) else self.map(lambda p: p * other)

    __rmul__ = __mul__

    @staticmethod
    def randn_like(tp: Triplane, generator: torch.Generator | None = None) -> Triplane:
        return tp.map(lambda p: torch.randn(p.shape, generator=generator, device=p.device, dtype=p.dtype))

    @staticmethod
    def randn(
        batch: int,
        channels: int,
        resolution: tuple[int, int, int],
        generator: torch.Generator | None = None,
        device: torch.device | str = "cpu",
    ) -> Triplane:
        x, y, z = resolution
        shapes = [(batch, channels, x, y), (batch, channels, x, z), (batch, channels, y, z)]
        return Triplane(*(torch.randn(s, generator=generator, device=device) for s in shapes))

    @staticmethod
    def empty(
        batch: int, channels: int, resolution: tuple[int, int, int], device: torch.device | str = "cpu"
    ) -> Triplane:
        """Planes of the right shapes with unset values (on the ``meta`` device: shapes only, no memory)."""
        x, y, z = resolution
        shapes = [(batch, channels, x, y), (batch, channels, x, z), (batch, channels, y, z)]
        return Triplane(*(torch.empty(s, device=device) for s in shapes))

    # ----------------------------------------------------------- persistence
    def state_dict(self) -> dict[str, torch.Tensor]:
        return {name: p.detach().cpu() for name, p in zip(PLANES, self.planes)}

    @classmethod
    def from_state_dict(cls, d: dict[str, torch.Tensor]) -> Triplane:
        return cls(d["xy"], d["xz"], d["yz"])

    # ---------------------------------------------------------------- lookup
    def lookup(self, points: torch.Tensor, reduce: str | None = None) -> torch.Tensor:
        """Bilinear feature lookup.

        Args:
            points: ``[B, N, 3]`` (or ``[N, 3]``, broadcast over the batch) in box coordinates [-1, 1].
            reduce: ``None`` keeps the three planes apart; ``"sum"`` adds them (what the decoder uses).
        Returns:
            ``[B, N, 3, C]`` (the features on the xy, xz and yz planes), or ``[B, N, C]`` with ``reduce="sum"``.
        """
        if points.dim() == 2:
            points = points.unsqueeze(0).expand(self.batch, -1, -1)
        if reduce == "sum" and lookup_fast_ok(self.planes, points):  # the same sum, gathered (kernels/pointops.py)
            return lookup_sum(self.planes, points, [PLANE_AXES[name] for name in PLANES])
        feats = [lookup_plane(p, points, PLANE_AXES[name]) for name, p in zip(PLANES, self.planes)]
        if reduce == "sum":
            return feats[0] + feats[1] + feats[2]
        return torch.stack(feats, dim=2)


def lookup_plane(plane: torch.Tensor, points: torch.Tensor, axes: tuple[int, int]) -> torch.Tensor:
    """Look up ``plane [B, C, A, B']`` at ``points [B, N, 3]`` projected on ``axes`` → ``[B, N, C]``.

    ``grid_sample`` indexes its input with (column, row) = (last dim, second to
    last), so the plane's column axis goes first.
    """
    row, col = axes
    grid = torch.stack([points[..., col], points[..., row]], dim=-1).unsqueeze(1)  # [B, 1, N, 2]
    out = F.grid_sample(plane, grid.to(plane.dtype), mode="bilinear", padding_mode="border", align_corners=False)
    return out[:, :, 0].transpose(1, 2)  # [B, N, C]


def plane_to_image(plane: torch.Tensor | np.ndarray, channels: str | int = "pca") -> np.ndarray:
    """Turn one plane ``[C, A, B]`` into an ``(A, B, 3)`` float image in [0, 1] for plotting.

    ``channels="pca"`` projects the C channels on their first three principal
    components (a common way to look at learned features); an ``int`` shows
    that single channel in grey.
    """
    p = plane.detach().cpu().numpy() if isinstance(plane, torch.Tensor) else np.asarray(plane)
    if p.ndim == 4:
        p = p[0]
    c, a, b = p.shape
    if isinstance(channels, int):
        img = p[channels]
        lo, hi = float(img.min()), float(img.max())
        img = (img - lo) / (hi - lo + 1e-8)
        return np.repeat(img[..., None], 3, axis=-1)
    return pca_project(p, *pca_basis(p))


def pca_basis(plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(C,)`` and the first three principal directions ``(C, 3)`` of a ``[C, A, B]`` plane.

    Each direction's sign is fixed (largest entry positive), so colours do not
    flip between calls; with fewer than 3 channels the basis is the identity.
    """
    c = plane.shape[0]
    flat = plane.reshape(c, -1).T.astype(np.float64)
    mean = flat.mean(0)
    if c < 3:
        return mean, np.eye(c, 3)
    _, _, vt = np.linalg.svd(flat - mean, full_matrices=False)
    basis = vt[:3].T
    signs = np.sign(basis[np.abs(basis).argmax(0), np.arange(3)])
    return mean, basis * np.where(signs == 0, 1.0, signs)


def pca_project(plane: np.ndarray, mean: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Project a ``[C, A, B]`` plane on a PCA basis → ``(A, B, 3)`` image in [0, 1] (each colour stretched)."""
    c, a, b = plane.shape
    proj = (plane.reshape(c, -1).T - mean) @ basis
    lo, hi = proj.min(0, keepdims=True), proj.max(0, keepdims=True)
    return ((proj - lo) / (hi - lo + 1e-8)).reshape(a, b, 3)
