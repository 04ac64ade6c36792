"""SSFID (G-Qual): DECOR-GAN's 3D classifier with weights by path, and the Fréchet distance it feeds."""

import numpy as np
import pytest
import torch

from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.evaluate.features import frechet_distance
from sin3dm_lite.evaluate.ssfid import VoxelClassifier, load_ssfid_classifier, ssfid, voxel_features


def test_frechet_distance_is_zero_for_equal_sets_and_the_squared_shift_for_a_shifted_one():
    f = np.random.default_rng(0).normal(size=(500, 6)) @ np.random.default_rng(1).normal(size=(6, 6))
    assert frechet_distance(f, f) == pytest.approx(0, abs=1e-8)
    shift = np.array([0.5, -1.0, 2.0, 0.0, 0.3, 1.5])
    assert frechet_distance(f, f + shift) == pytest.approx(float(shift @ shift), rel=1e-8)


def test_frechet_distance_of_two_gaussians_in_closed_form():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(20000, 2)), rng.normal(size=(20000, 2)) * 2.0  # N(0, I) and N(0, 4I)
    # |Δμ|² + tr(I + 4I - 2·(4I)^½) = 2·(1 + 4 - 4) = 2
    assert frechet_distance(a, b) == pytest.approx(2.0, rel=0.05)


def _grid(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.arange(32)
    h = 12 + 4 * np.sin(x / rng.uniform(2, 5))[:, None] + 3 * np.cos(x / rng.uniform(2, 5))[None, :]
    return np.arange(32)[None, :, None] < h[:, None, :]


def test_ssfid_with_random_weights_from_a_file(tmp_path):
    torch.manual_seed(0)
    path = tmp_path / "Clsshapenet_128.pth"
    torch.save(VoxelClassifier().state_dict(), path)
    net = load_ssfid_classifier(path)
    a, b = _grid(0), _grid(1)
    assert voxel_features(a, net).shape == (8**3, 64)  # layer 2: 64 channels on a 32/4 = 8³ lattice
    assert ssfid(a, a, net) == pytest.approx(0, abs=1e-8)
    assert ssfid(a, b, net) > 1e-6
    assert ssfid(a, b, net) == pytest.approx(frechet_distance(voxel_features(a, net), voxel_features(b, net)))
    logits, z = net(torch.as_tensor(a, dtype=torch.float32)[None, None])
    assert logits.shape == (1, 24) and z.shape == (1, 512)


def test_missing_or_wrong_weights_and_mismatched_grids_are_one_line(tmp_path):
    with pytest.raises(Sin3DMInputError, match="Clsshapenet_128.pth from https://"):
        load_ssfid_classifier(tmp_path / "nope.pth")
    torch.save({"conv_1.weight": torch.zeros(3)}, tmp_path / "bad.pth")
    with pytest.raises(Sin3DMInputError, match="do not fit the classifier"):
        load_ssfid_classifier(tmp_path / "bad.pth")
    with pytest.raises(Sin3DMInputError, match="one size"):
        ssfid(_grid(0), _grid(0)[:, :, :16], VoxelClassifier())
