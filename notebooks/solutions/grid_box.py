"""Exercise (notebook 01): the voxel counts and the box of a shape's grid."""

import numpy as np


def grid_box(extent, resolution: int):
    """``extent`` (3,) side lengths, ``resolution`` voxels along the longest → ``(shape, aabb)``."""
    extent = np.asarray(extent, np.float64)
    share = np.floor(resolution * extent / extent.max())  # int(): rounded down; the longest axis gets `resolution`
    shape = tuple(int(max(8, np.ceil(n / 8) * 8)) for n in share)  # up to a multiple of 8
    half = np.array(shape) / max(shape)  # the longest side spans [-1, 1]; voxels are cubes
    return shape, np.concatenate([-half, half])
