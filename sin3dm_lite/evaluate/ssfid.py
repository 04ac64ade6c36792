"""SSFID, the paper's G-Qual: a Fréchet distance between a 3D classifier's local features of two voxel grids.

SSG and Sin3DM score a generated shape's geometry the way SinGAN's SIFID scores a picture: both 128³ occupancy grids
go through a 3D CNN pre-trained on ShapeNet (DECOR-GAN's shape classifier), a Gaussian is fitted to the feature
vectors at every position of an early layer, and :func:`~sin3dm_lite.evaluate.features.frechet_distance` compares
the two. The weights, ``Clsshapenet_128.pth``, are the Sin3DM authors' (:data:`SSFID_URL`), not shipped: give their
path to :func:`load_ssfid_classifier` (nothing is downloaded).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import Sin3DMInputError
from .features import frechet_distance

#: the classifier's weight file and where the authors publish it (documentation only: nothing is downloaded)
SSFID_WEIGHTS = "Clsshapenet_128.pth"
SSFID_URL = "https://drive.google.com/file/d/1HjnDudrXsNY4CYhIGhH4Q0r3-NBnBaiC/view"
#: the layer whose per-position features SSFID compares (the authors' default)
SSFID_LAYER = 2


class VoxelClassifier(nn.Module):
    """DECOR-GAN's 3D classifier for 128³ occupancy grids; parameter names as in ``Clsshapenet_128.pth``."""

    def __init__(self, width: int = 32, z_dim: int = 512, classes: int = 24):
        super().__init__()
        chans = [1, width, 2 * width, 4 * width, 8 * width, z_dim]
        for i in range(5):  # conv_1 ... conv_5: 4³ kernels, stride 2, each halves the grid
            self.add_module(f"conv_{i + 1}", nn.Conv3d(chans[i], chans[i + 1], 4, stride=2, padding=1))
        self.linear1 = nn.Linear(z_dim, classes)

    def features(self, voxels: torch.Tensor, layer: int = SSFID_LAYER) -> torch.Tensor:
        """``[B, 1, D, H, W]`` → the activations after block ``layer`` (1-4): ``[B, C, D/2^layer, ...]``."""
        x = voxels
        for i in range(1, layer + 1):  # conv → instance norm (no learned scale) → leaky ReLU
            x = F.leaky_relu(F.instance_norm(getattr(self, f"conv_{i}")(x)), 0.01)
        return x

    def forward(self, voxels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Class logits ``[B, classes]`` and the pooled code ``z [B, z_dim]``."""
        z = F.adaptive_avg_pool3d(self.conv_5(self.features(voxels, 4)), 1).flatten(1)
        return self.linear1(F.leaky_relu(z, 0.01)), z


def load_ssfid_classifier(path) -> VoxelClassifier:
    """The classifier with the authors' weights from ``path`` (``Clsshapenet_128.pth``), in eval mode; a missing,
    unreadable or misfitting file is one :class:`~sin3dm_lite.errors.Sin3DMInputError` line saying where to get it."""
    path = Path(path)
    get = f"download {SSFID_WEIGHTS} from {SSFID_URL} (the Sin3DM authors' evaluation weights) and pass its path"
    if not path.is_file():
        raise Sin3DMInputError(f"SSFID needs DECOR-GAN's classifier weights: '{path}' not found; {get}")
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - truncated, not a checkpoint, holds code: one clear line
        raise Sin3DMInputError(f"cannot read SSFID weights '{path}' ({type(e).__name__}); {get}") from None
    net = VoxelClassifier()
    want = net.state_dict()
    sd = {k.removeprefix("module."): v for k, v in sd.items()} if isinstance(sd, dict) else {}
    bad = [k for k, v in want.items() if not isinstance(sd.get(k), torch.Tensor) or sd[k].shape != v.shape]
    if bad:
        raise Sin3DMInputError(f"SSFID weights '{path}' do not fit the classifier ('{bad[0]}'); {get}")
    net.load_state_dict({k: sd[k].float() for k in want})
    return net.eval()


def _voxels(grid, name: str) -> torch.Tensor:
    arr = np.asarray(grid)
    if arr.ndim != 3 or min(arr.shape) < 16:
        raise Sin3DMInputError(
            f"SSFID compares 3D occupancy grids (128³ in the paper); the {name} has shape {arr.shape}"
        )
    return torch.as_tensor(arr.astype(np.float32))[None, None]


@torch.no_grad()
def voxel_features(grid, classifier: VoxelClassifier, layer: int = SSFID_LAYER) -> np.ndarray:
    """One occupancy grid ``(D, H, W)`` → its feature vectors at every position of ``layer``: ``(positions, C)``."""
    device = next(classifier.parameters()).device
    f = classifier.features(_voxels(grid, "grid").to(device), layer)[0]  # [C, d, h, w]
    return f.flatten(1).T.double().cpu().numpy()


def ssfid(reference, sample, classifier: VoxelClassifier, layer: int = SSFID_LAYER) -> float:
    """SSFID (G-Qual, lower = better) of one sample against the input: both occupancy grids of the same shape
    (the paper: 128 voxels along the longest side), through :func:`voxel_features`, then the Fréchet distance."""
    ref, gen = _voxels(reference, "reference"), _voxels(sample, "sample")
    if ref.shape != gen.shape:
        raise Sin3DMInputError(
            f"SSFID compares grids of one size: the reference is {tuple(ref.shape[2:])}, the sample "
            f"{tuple(gen.shape[2:])}; voxelise both at the same resolution"
        )
    return frechet_distance(voxel_features(reference, classifier, layer), voxel_features(sample, classifier, layer))


__all__ = [
    "SSFID_LAYER",
    "SSFID_URL",
    "SSFID_WEIGHTS",
    "VoxelClassifier",
    "load_ssfid_classifier",
    "ssfid",
    "voxel_features",
]
