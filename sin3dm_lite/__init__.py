"""sin3dm-lite: a readable reimplementation of Sin3DM (ICLR 2024) for learning and for use.

From one textured mesh: a truncated SDF + colour grid, a triplane latent, a
small-receptive-field diffusion model on the triplane, and new textured
meshes. The stages, in the order data flows (a module imports only from
stages before it)::

    Data      mesh_io (read meshes) · box (box/grid geometry) · grid (mesh → TSDF grid)
    Model     triplane · training (what both trainers share) · autoencoder (grid → latent, decoder)
              decode (decoder queries, SDF grids) · unet · diffusion (training, sampling)
    Generate  extract (SDF → textured mesh) · export (OBJ / GLB writers) · control (what to sample: outpaint, ...)
    Eval      metrics · calibrate (the diversity knob per shape)          Show  viz (figures) · widgets (panels) · viewer (k3d / HTML)
    Teach     lesson2d (the method on one 2D image) · exercises (``check_…`` a piece of the method you wrote)
    Facade    pipeline (Sin3DM: fit, sample, save, load) · runs (RUN → model, cached fits) · cli · examples · pretrained

Everything a notebook or script needs is importable from here::

    from sin3dm_lite import Sin3DM, get_preset, build_example, mesh_to_grid, extract_mesh

The names load on first use, so ``import sin3dm_lite`` stays quick (the CLI
answers bad arguments before torch is imported). The Show modules are used as
namespaces: ``from sin3dm_lite import viz, widgets, viewer``.
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name → module that defines it
_API = {
    # facade and settings
    "Sin3DM": "pipeline",
    "Samples": "pipeline",
    "resolve_mesh": "pipeline",
    "Config": "config",
    "get_preset": "config",
    "notebook_preset": "config",
    "fast_mode": "config",
    "pretrained_path": "pretrained",
    "shipped_names": "pretrained",
    "shipped_examples": "pretrained",
    "open_run": "runs",
    "Sin3DMInputError": "errors",
    "get_device": "device",
    "count_parameters": "device",
    # data
    "DEFAULT_EXAMPLE": "examples",
    "build_example": "examples",
    "list_examples": "examples",
    "write_example": "examples",
    "TexturedMesh": "mesh_io",
    "Material": "mesh_io",
    "Normalization": "mesh_io",
    "load_mesh": "mesh_io",
    "load_any": "mesh_io",
    "tangent_frames": "mesh_io",
    "grid_shape": "box",
    "margin_scale": "box",
    "ShapeGrid": "grid",
    "PBR_CHANNELS": "grid",
    "mesh_to_grid": "grid",
    "load_grid": "grid",
    "save_grid": "grid",
    # model
    "Triplane": "triplane",
    "TriplaneEncoder": "autoencoder",
    "TriplaneDecoder": "autoencoder",
    "AutoencoderTrainer": "autoencoder",
    "grid_tensor": "autoencoder",
    "decode_grid": "decode",
    "prepare": "decode",
    "query_points": "decode",
    "reconstructed_grid": "decode",
    "TriplaneUNet": "unet",
    "TriplaneConv": "unet",
    "rollout_parts": "unet",
    "block_layout": "unet",
    "receptive_field": "unet",
    "analytic_receptive_field": "unet",
    "layer_walk": "unet",
    "layers_receptive_field": "unet",
    "NoiseSchedule": "diffusion",
    "DiffusionTrainer": "diffusion",
    "sample": "diffusion",
    "predict_clean": "diffusion",
    "diffusion_loss": "diffusion",
    "triplane_mse": "diffusion",
    # generate
    "extract_mesh": "extract",
    "marching_cubes": "extract",
    "pbr_maps": "extract",
    "export_mesh": "export",
    # eval
    "reconstruction_metrics": "metrics",
    "voxelize": "metrics",
    "input_occupancy": "metrics",
    "iou": "metrics",
    "g_div": "metrics",
    "lp_scores": "metrics",
    "geometry_scores": "metrics",
    "patch_swd": "metrics",
    "render_div": "metrics",
    "texture_scores": "metrics",
    "load_feature_weights": "metrics",
    "sifid": "metrics",
    "lpips": "metrics",
    "calibrate_diversity": "calibrate",
    "Calibration": "calibrate",
    # exercises: write a piece of the method, check it against the library
    "ExerciseError": "exercises",
    "check_q_sample": "exercises",
    "check_ddpm_posterior": "exercises",
    "check_ddim_step": "exercises",
    "check_triplane_lookup": "exercises",
    "check_receptive_field": "exercises",
    "check_rollout": "exercises",
    "check_best_patch_iou": "exercises",
}

_MODULES = {"viz", "widgets", "viewer", "metrics", "render", "examples", "box", "extract", "export", "mesh_io",
            "lesson2d", "exercises"}

__all__ = sorted(_API) + sorted(_MODULES)


def __getattr__(name: str):
    if name in _API:
        value = getattr(importlib.import_module(f".{_API[name]}", __name__), name)
        globals()[name] = value  # next time without this function
        return value
    if name in _MODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'sin3dm_lite' has no attribute '{name}'")


def __dir__():
    return sorted(set(globals()) | set(__all__))
