"""Exercise (notebook 00): the latent and the box of a resized sample."""

import numpy as np


def retarget(resolution, aabb, factors):
    """``resolution`` texels (X, Y, Z), ``aabb`` (6,) centred on the origin, ``factors`` (3,) → ``(new_resolution, new_aabb)``."""
    old = np.array(resolution)
    new = np.maximum(4, np.round(old * np.asarray(factors)))  # whole texels, at least 4
    scale = new / old  # the rounded ratio: every texel keeps its size in space
    aabb = np.asarray(aabb, np.float64)
    return tuple(int(n) for n in new), np.concatenate([aabb[:3] * scale, aabb[3:] * scale])
