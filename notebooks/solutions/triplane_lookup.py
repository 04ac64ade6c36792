"""Exercise (notebook 02): a point's features on the three planes, by bilinear interpolation."""

import torch
import torch.nn.functional as F


def lookup(xy, xz, yz, points):
    """``points [B, N, 3]`` in [-1, 1] → features ``[B, N, 3, C]`` read on xy at (x, y), xz at (x, z), yz at (y, z)."""
    feats = []
    for plane, (row, col) in ((xy, (0, 1)), (xz, (0, 2)), (yz, (1, 2))):
        # grid_sample wants (x, y) = (column, row) in [-1, 1], as a [B, H_out, W_out, 2] grid: here [B, 1, N, 2]
        grid = torch.stack([points[..., col], points[..., row]], -1)[:, None]
        f = F.grid_sample(plane, grid, mode="bilinear", padding_mode="border", align_corners=False)  # [B, C, 1, N]
        feats.append(f[:, :, 0].transpose(1, 2))  # [B, N, C]
    return torch.stack(feats, 2)
