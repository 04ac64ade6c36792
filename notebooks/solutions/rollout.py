"""Exercise (notebook 03): what a TriplaneConv feeds the xy plane's Conv2d (the paper's rollout, Fig. 3b)."""

import torch


def rollout_xy(xy, xz, yz):
    """``[xy, mean_z(xz) along y, mean_z(yz) along x]`` on channels: ``[B, 3C, X, Y]``."""
    from_xz = xz.mean(3, keepdim=True)  # [B, C, X, 1]: a feature per x
    from_yz = yz.mean(3)[:, :, None, :]  # [B, C, 1, Y]: a feature per y
    return torch.cat([xy, from_xz.expand_as(xy), from_yz.expand_as(xy)], 1)
