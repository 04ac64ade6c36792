"""The figures of every stage in one namespace (``from sin3dm_lite import viz``; ``viz.plot_slice(grid)``).

Each function takes plain data (numpy arrays, :class:`~sin3dm_lite.data.grid.ShapeGrid`,
:class:`~sin3dm_lite.model.triplane.Triplane`) and *returns* a ``matplotlib.figure.Figure`` that pyplot does not
keep, so in Jupyter each appears once, as the value of the cell, and a script saves it with ``fig.savefig(path)``.
They live in one module per stage: ``figures`` (what they share), ``data_figures``, ``model_figures``,
``diffusion_figures``, ``sample_figures``, ``eval_figures``.
"""

# ruff: noqa: F401 (this module is the namespace)
from __future__ import annotations

from .data_figures import (
    pbr_map_images,
    pbr_slice_images,
    plot_grid_slices,
    plot_pbr_maps,
    plot_pbr_slices,
    plot_points,
    plot_slice,
    plot_texture,
    plot_truncation,
    plot_uv_layout,
)
from .diffusion_figures import moving_average, plot_denoising, plot_losses, plot_schedule
from .eval_figures import plot_iou_matrix, plot_layer_variation, plot_patch_matches, plot_picture, plot_render_pairs
from .figures import AXES, NEUTRAL, SDF_CMAP, color_slice_image, grid_slice
from .model_figures import (
    RF_LEVEL,
    measured_width,
    plot_plane_axes,
    plot_receptive_field,
    plot_receptive_fields,
    plot_triplane,
    plot_triplane_conv,
    triplane_images,
)
from .sample_figures import (
    plot_beside_input,
    plot_diversity_curve,
    plot_meshes,
    plot_plan,
    plot_projections,
    plot_samples_slices,
)
