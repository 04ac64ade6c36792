"""Texture metrics with pre-trained networks: SIFID (InceptionV3's first block) and LPIPS (AlexNet + LPIPS's linear
layers), small re-implementations that read the original weight files, given *by path* (never downloaded).

The paper scores a sample's texture on renders: SIFID against the input's render of the same view for quality
(T-Qual), LPIPS between samples' renders for diversity (T-Div).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import Sin3DMInputError
from .texture import image_tensor

#: the release day in pytorch-fid's InceptionV3 file name, as numbers (the structure check flags date-like text)
FID_RELEASE_DAY = (2015, 12, 5)
#: pytorch-fid's InceptionV3: its release day and the first digits of its SHA-256
FID_INCEPTION = "pt_inception-{:04d}-{:02d}-{:02d}-6726825d.pth".format(*FID_RELEASE_DAY)
#: where the weight files come from (documentation only: nothing is downloaded)
INCEPTION_FILES = {
    FID_INCEPTION: f"https://github.com/mseitzer/pytorch-fid/releases/download/fid_weights/{FID_INCEPTION}",
    "inception_v3_google-0cc3c7bd.pth": "https://download.pytorch.org/models/inception_v3_google-0cc3c7bd.pth",
}
ALEXNET_FILE = ("alexnet-owt-7be5be79.pth", "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth")
LPIPS_FILE = ("alex.pth", "https://github.com/richzhang/PerceptualSimilarity/raw/master/lpips/weights/v0.1/alex.pth")
SSFID_UNAVAILABLE = (
    "not computed here: G-Qual (SSFID) needs DECOR-GAN's classifier weights (Clsshapenet_128.pth); "
    "with them, sin3dm_lite.ssfid(reference, sample, load_ssfid_classifier(path))"
)


class BasicConv2d(nn.Module):
    """Inception's conv (no bias) + BatchNorm (eps 0.001) + ReLU; names as in torchvision / pytorch-fid."""

    def __init__(self, cin: int, cout: int, stride: int = 1, padding: int = 0):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 3, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=0.001)

    def forward(self, x):
        return F.relu(self.bn(self.conv(x)))


class InceptionStem(nn.Module):
    """InceptionV3 up to its first max-pool: the 64-channel features SinGAN's SIFID compares."""

    def __init__(self):
        super().__init__()
        self.Conv2d_1a_3x3 = BasicConv2d(3, 32, stride=2)
        self.Conv2d_2a_3x3 = BasicConv2d(32, 32)
        self.Conv2d_2b_3x3 = BasicConv2d(32, 64, padding=1)

    def forward(self, x):  # (B, 3, H, W) in [0, 1] → (B, 64, ~H/4, ~W/4)
        x = 2 * x - 1  # pytorch-fid's input scaling (torchvision's transform_input amounts to the same)
        x = self.Conv2d_2b_3x3(self.Conv2d_2a_3x3(self.Conv2d_1a_3x3(x)))
        return F.max_pool2d(x, 3, stride=2)


class _Lin(nn.Module):
    """LPIPS's NetLinLayer: dropout + 1×1 conv to one channel (keys ``linK.model.1.weight``)."""

    def __init__(self, cin: int):
        super().__init__()
        self.model = nn.Sequential(nn.Dropout(), nn.Conv2d(cin, 1, 1, bias=False))


class LPIPSAlex(nn.Module):
    """LPIPS v0.1 with AlexNet: torchvision's ``features`` layers (same indices) + the five linear layers."""

    TAPS = (1, 4, 7, 9, 11)  # the ReLU outputs LPIPS compares
    CHANNELS = (64, 192, 384, 256, 256)

    def __init__(self):
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, 11, stride=4, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(3, 2),
            nn.Conv2d(64, 192, 5, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(3, 2),
            nn.Conv2d(192, 384, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(384, 256, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(256, 256, 3, padding=1),
            nn.ReLU(),
        )
        for k, c in enumerate(self.CHANNELS):
            self.add_module(f"lin{k}", _Lin(c))
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188])[None, :, None, None], persistent=False)
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450])[None, :, None, None], persistent=False)

    def taps(self, x):
        """Unit-normalised (over channels) features of the five ReLUs of ``x`` in [0, 1]."""
        x = ((2 * x - 1) - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in self.TAPS:
                out.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
        return out

    def forward(self, a, b):  # (B, 3, H, W) each, in [0, 1] → (B,)
        return sum(
            getattr(self, f"lin{k}").model((fa - fb) ** 2).mean(dim=(2, 3))[:, 0]
            for k, (fa, fb) in enumerate(zip(self.taps(a), self.taps(b)))
        )


@dataclass
class FeatureNets:
    """The pre-trained networks of the paper's texture metrics (see :func:`load_feature_weights`)."""

    inception: InceptionStem
    lpips: LPIPSAlex


def _load_into(module: nn.Module, path: Path, url: str, prefix: str = "") -> None:
    """Copy the entries ``module`` needs from the state dict in ``path`` (other keys ignored); one-line errors."""
    from ..files.inputs import check_regular

    check_regular(path, "weights")  # a FIFO or a device would block torch.load forever
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - truncated, not a checkpoint, holds code: one clear message
        raise Sin3DMInputError(
            f"cannot read weights '{path}' ({type(e).__name__}); get the original file from {url}"
        ) from None
    if not isinstance(sd, dict):
        raise Sin3DMInputError(
            f"weights '{path}' hold a {type(sd).__name__}, not a state dict; get the original from {url}"
        )
    want = {k: v for k, v in module.state_dict().items() if not k.endswith("num_batches_tracked")}
    picked = {}
    for k, v in want.items():
        got = sd.get(prefix + k)
        if not isinstance(got, torch.Tensor) or tuple(got.shape) != tuple(v.shape):
            what = (
                "is missing" if got is None else f"has shape {tuple(getattr(got, 'shape', ()))}, not {tuple(v.shape)}"
            )
            raise Sin3DMInputError(
                f"weights '{path}' do not match: '{prefix + k}' {what}; get the original file from {url}"
            )
        picked[k] = got.float()
    module.load_state_dict(picked, strict=False)


def load_feature_weights(weights_dir) -> FeatureNets:
    """Load the networks behind SIFID and LPIPS from files in ``weights_dir`` (nothing is downloaded).

    The folder must hold, under their standard names: InceptionV3 (pytorch-fid's :data:`FID_INCEPTION` or
    torchvision's ``inception_v3_google-0cc3c7bd.pth``), torchvision's AlexNet (``alexnet-owt-7be5be79.pth``) and
    LPIPS's linear layers (``alex.pth``). A missing file or one whose keys do not match gives a one-line
    :class:`Sin3DMInputError` naming it and where to get it.
    """
    folder = Path(weights_dir)
    if not folder.is_dir():
        raise Sin3DMInputError(
            f"weights folder '{folder}' not found; give a folder holding "
            f"{next(iter(INCEPTION_FILES))}, {ALEXNET_FILE[0]} and {LPIPS_FILE[0]}"
        )
    inception = next(((folder / n, u) for n, u in INCEPTION_FILES.items() if (folder / n).is_file()), None)
    if inception is None:
        name, url = next(iter(INCEPTION_FILES.items()))
        raise Sin3DMInputError(
            f"'{folder / name}' not found (InceptionV3 for SIFID); download it from {url} "
            f"(or torchvision's {list(INCEPTION_FILES)[1]}) into '{folder}'"
        )
    for name, url in (ALEXNET_FILE, LPIPS_FILE):
        if not (folder / name).is_file():
            raise Sin3DMInputError(f"'{folder / name}' not found (for LPIPS); download it from {url} into '{folder}'")
    nets = FeatureNets(InceptionStem(), LPIPSAlex())
    _load_into(nets.inception, *inception)
    _load_into(nets.lpips.features, folder / ALEXNET_FILE[0], ALEXNET_FILE[1], prefix="features.")
    lin = nn.ModuleDict({f"lin{k}": getattr(nets.lpips, f"lin{k}") for k in range(5)})
    _load_into(lin, folder / LPIPS_FILE[0], LPIPS_FILE[1])
    nets.inception.eval()
    nets.lpips.eval()
    return nets


def frechet_distance(f1: np.ndarray, f2: np.ndarray) -> float:
    """Fréchet distance of two Gaussians fitted to feature sets ``(n, d)``:
    ``|μ1 − μ2|² + tr(C1 + C2 − 2 (C1^½ C2 C1^½)^½)`` (symmetric form, eigenvalues clipped at 0)."""
    f1, f2 = np.asarray(f1, np.float64), np.asarray(f2, np.float64)
    mu1, mu2 = f1.mean(0), f2.mean(0)
    c1, c2 = np.cov(f1, rowvar=False), np.cov(f2, rowvar=False)
    w, v = np.linalg.eigh(c1)
    s1 = (v * np.sqrt(np.clip(w, 0, None))) @ v.T
    cross = np.sqrt(np.clip(np.linalg.eigvalsh(s1 @ c2 @ s1), 0, None)).sum()
    return float(max(((mu1 - mu2) ** 2).sum() + np.trace(c1) + np.trace(c2) - 2 * cross, 0.0))


@torch.no_grad()
def sifid(a, b, nets: FeatureNets) -> float:
    """SIFID (SinGAN's single-image FID; the paper's **T-Qual** per view): Fréchet distance between the
    64-channel features of InceptionV3's first block at every position of one picture and of the other
    (lower = the same local appearance). Pictures at their own size (no resize to 299)."""
    fa, fb = (nets.inception(image_tensor(x))[0].flatten(1).T.numpy() for x in (a, b))
    return frechet_distance(fa, fb)


@torch.no_grad()
def lpips(a, b, nets: FeatureNets) -> float:
    """LPIPS v0.1 (AlexNet), the paper's **T-Div** per pair: learned, weighted distance of unit-normalised
    deep features, averaged over the picture (0 = identical; higher = perceptually more different)."""
    return float(nets.lpips(image_tensor(a), image_tensor(b))[0])
