"""Mesh → truncated SDF + colour grid, the representation the autoencoder learns from.

(Implementation of ``mesh_to_grid`` follows below the data type.)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .mesh_io import Normalization


@dataclass
class ShapeGrid:
    """The paper's input representation of one shape.

    Attributes:
        sdf: ``(H, W, D)`` float32 truncated signed distance (negative inside),
            clipped to ``±threshold``; axis 0 is x, 1 is y, 2 is z.
        color: ``(H, W, D, K)`` float32 in [0, 1] (K = 3 for RGB); 0 outside the band.
        aabb: ``(6,)`` the symmetric box ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in
            normalised coordinates, ``±n_axis / n_max``.
        threshold: truncation distance in normalised units (3 voxels by default).
        normalization: maps the input file's coordinates to the normalised frame.
        points / point_sdf / point_color: near-surface training samples
            (normalised coordinates) with their exact truncated SDF and colour.
        name: label of the source mesh.
    """

    sdf: np.ndarray
    color: np.ndarray
    aabb: np.ndarray
    threshold: float
    normalization: Normalization
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    point_sdf: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.float32))
    point_color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    name: str = "shape"

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.sdf.shape)  # type: ignore[return-value]

    @property
    def voxel_size(self) -> float:
        """Edge length of one (cubic) voxel in normalised units."""
        return float((self.aabb[3] - self.aabb[0]) / self.sdf.shape[0])

    def axis_coords(self, axis: int) -> np.ndarray:
        """Cell-centred voxel coordinates along one axis: ``min + (k + 0.5) / n * size``."""
        n = self.sdf.shape[axis]
        lo, hi = self.aabb[axis], self.aabb[axis + 3]
        return (lo + (np.arange(n) + 0.5) / n * (hi - lo)).astype(np.float32)

    def voxel_centers(self) -> np.ndarray:
        """``(H, W, D, 3)`` coordinates of every voxel centre."""
        return np.stack(np.meshgrid(*(self.axis_coords(a) for a in range(3)), indexing="ij"), axis=-1)

    def to_box(self, points: np.ndarray) -> np.ndarray:
        """Normalised coordinates → box coordinates in [-1, 1] (what triplane lookups take)."""
        lo, hi = self.aabb[:3], self.aabb[3:]
        return (2 * (np.asarray(points) - lo) / (hi - lo) - 1).astype(np.float32)

    def from_box(self, points: np.ndarray) -> np.ndarray:
        lo, hi = self.aabb[:3], self.aabb[3:]
        return ((np.asarray(points) + 1) / 2 * (hi - lo) + lo).astype(np.float32)
