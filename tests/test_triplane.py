"""Triplane lookups: which plane axis is which, texel centres, the border."""

import torch

from sin3dm_lite.model.triplane import Triplane


def centres(n):
    return -1 + (2 * torch.arange(n, dtype=torch.float64) + 1) / n  # cell-centred, align_corners=False


def linear_triplane(shape=(4, 6, 8)):
    """Each plane holds 10 · (its row coordinate) + (its column coordinate) at its texel centres."""
    x, y, z = (centres(n) for n in shape)
    plane = lambda r, c: (10 * r[:, None] + c[None, :])[None, None]  # noqa: E731  [1, 1, rows, cols]
    return Triplane(plane(x, y), plane(x, z), plane(y, z))


def test_sample_reads_each_plane_on_its_own_axes():
    tp = linear_triplane()
    # inside the texel-centre hull bilinear interpolation of a linear function is exact
    pts = torch.tensor([[0.1, -0.3, 0.5], [-0.6, 0.7, -0.8], [0.0, 0.0, 0.0]], dtype=torch.float64)
    got = tp.lookup(pts)[0, :, :, 0]  # [N, 3 planes]
    x, y, z = pts.T
    want = torch.stack([10 * x + y, 10 * x + z, 10 * y + z], 1)
    torch.testing.assert_close(got, want)
    torch.testing.assert_close(tp.lookup(pts, reduce="sum")[0, :, 0], want.sum(1))


def test_sample_hits_texel_centres_and_clamps_at_the_border():
    tp = linear_triplane()
    x, y, z = centres(4), centres(6), centres(8)
    pts = torch.tensor([[x[0], y[5], z[3]], [1.5, -2.0, 0.0]], dtype=torch.float64)
    got = tp.lookup(pts)[0, :, :, 0]
    torch.testing.assert_close(got[0], torch.stack([10 * x[0] + y[5], 10 * x[0] + z[3], 10 * y[5] + z[3]]))
    # outside the box: the value of the outermost texel centres (x = 1 - 1/4, y = -1 + 1/6)
    xb, yb = x[-1], y[0]
    torch.testing.assert_close(got[1], torch.stack([10 * xb + yb, 10 * xb + 0.0, 10 * yb + 0.0]))


def test_pca_image_shows_the_strongest_pattern_first():
    import numpy as np

    from sin3dm_lite.model.triplane import pca_basis, plane_to_image

    rng = np.random.default_rng(0)
    a, b = np.meshgrid(np.linspace(-1, 1, 10), np.linspace(-1, 1, 7), indexing="ij")
    strong, weak = np.sin(3 * a), np.cos(2 * b)  # two spatial patterns, mixed into 6 channels
    plane = (rng.normal(size=(6, 1, 1)) * 5 * strong + rng.normal(size=(6, 1, 1)) * weak).astype(np.float32)
    img = plane_to_image(plane)
    assert img.shape == (10, 7, 3) and img.min() >= 0 and img.max() <= 1
    assert abs(np.corrcoef(img[..., 0].ravel(), strong.ravel())[0, 1]) > 0.999  # red: the strong pattern
    assert abs(np.corrcoef(img[..., 1].ravel(), weak.ravel())[0, 1]) > 0.99  # green: the next one
    # the sign of every direction is fixed: the same plane, negated, gives the same basis up to the mean
    _, basis = pca_basis(plane)
    _, basis_neg = pca_basis(-plane)
    np.testing.assert_allclose(basis[:, :2], basis_neg[:, :2], atol=1e-6)
