"""sin3dm-lite: a readable reimplementation of Sin3DM (ICLR 2024) for learning and for use.

From one textured mesh: a truncated SDF + colour grid, a triplane latent, a small-receptive-field diffusion model
on the triplane, and new textured meshes. One sub-package per stage, in the order data flows (base, ``data``,
``model``, ``generate``, ``evaluate``, ``show`` and ``teach``, then the app: ``pipeline``, ``app``, ``auto``,
``cli``); a module imports only from its own level or a lower one (``tests/test_architecture.py`` holds the table,
docs/architecture.md describes it).

Everything a notebook or script needs is importable from here::

    from sin3dm_lite import Sin3DM, get_preset, build_example, mesh_to_grid, extract_mesh

The names load on first use, so ``import sin3dm_lite`` stays quick (the CLI answers bad arguments before torch is
imported). The Show modules are used as namespaces: ``from sin3dm_lite import viz, widgets, viewer``.
"""

from __future__ import annotations

import importlib

from .app.threads import apply_policy as _apply_thread_policy

_apply_thread_policy()  # before torch loads (app/threads.py says why)

__version__ = "0.1.0"

#: public name → module that defines it
_API = {
    # facade and settings
    "Sin3DM": "pipeline",
    "Samples": "app.sampling",
    "resolve_mesh": "data.source",
    "Config": "data.config",
    "get_preset": "presets",
    "notebook_preset": "presets",
    "fast_mode": "presets",
    "pretrained_path": "app.pretrained",
    "shipped_names": "app.pretrained",
    "shipped_examples": "app.pretrained",
    "open_run": "pipeline",
    "Sin3DMInputError": "errors",
    "get_device": "app.device",
    "count_parameters": "app.device",
    # data
    "DEFAULT_EXAMPLE": "examples",
    "build_example": "examples",
    "list_examples": "examples",
    "write_example": "examples",
    "TexturedMesh": "data.mesh",
    "Material": "data.mesh",
    "Normalization": "data.mesh",
    "load_mesh": "formats.load",
    "load_any": "formats.load",
    "tangent_frames": "data.mesh",
    "grid_shape": "data.box",
    "margin_scale": "data.box",
    "ShapeGrid": "data.grid",
    "PBR_CHANNELS": "data.grid",
    "mesh_to_grid": "data.grid",
    "load_grid": "data.grid",
    "save_grid": "data.grid",
    # model
    "Triplane": "model.triplane",
    "TriplaneEncoder": "model.autoencoder",
    "TriplaneDecoder": "model.autoencoder",
    "AutoencoderTrainer": "model.autoencoder",
    "grid_tensor": "model.autoencoder",
    "decode_grid": "model.decode",
    "prepare": "model.decode",
    "query_points": "model.decode",
    "reconstructed_grid": "model.decode",
    "TriplaneUNet": "model.unet",
    "TriplaneConv": "model.unet",
    "rollout_parts": "model.unet",
    "block_layout": "model.unet",
    "receptive_field": "teach.receptive_field",
    "analytic_receptive_field": "teach.receptive_field",
    "layer_walk": "teach.receptive_field",
    "layers_receptive_field": "teach.receptive_field",
    "NoiseSchedule": "model.schedule",
    "ddim_timesteps": "model.schedule",
    "DiffusionTrainer": "model.diffusion",
    "sample": "model.diffusion",
    "predict_clean": "model.diffusion",
    "diffusion_loss": "model.diffusion",
    "triplane_mse": "model.diffusion",
    # generate
    "extract_mesh": "generate.extract",
    "marching_cubes": "generate.extract",
    "pbr_maps": "generate.bake",
    "export_mesh": "formats.export",
    # eval
    "reconstruction_metrics": "evaluate.metrics",
    "voxelize": "evaluate.metrics",
    "input_occupancy": "evaluate.metrics",
    "iou": "evaluate.metrics",
    "g_div": "evaluate.metrics",
    "lp_scores": "evaluate.metrics",
    "geometry_scores": "evaluate.metrics",
    "patch_swd": "evaluate.metrics",
    "render_div": "evaluate.metrics",
    "texture_scores": "evaluate.metrics",
    "load_feature_weights": "evaluate.metrics",
    "sifid": "evaluate.metrics",
    "lpips": "evaluate.metrics",
    "ssfid": "evaluate.ssfid",
    "load_ssfid_classifier": "evaluate.ssfid",
    "calibrate_diversity": "evaluate.calibrate",
    "Calibration": "evaluate.calibration_record",
    # exercises: write a piece of the method, check it against the library
    "ExerciseError": "teach.checking",
    "check_q_sample": "teach.exercises",
    "check_ddpm_posterior": "teach.exercises",
    "check_ddim_step": "teach.exercises",
    "check_triplane_lookup": "teach.exercises",
    "check_receptive_field": "teach.exercises",
    "check_rollout": "teach.exercises",
    "check_best_patch_iou": "teach.exercises",
    "check_grid_box": "teach.shape_exercises",
    "check_retarget": "teach.shape_exercises",
    "check_regenerate_mask": "teach.shape_exercises",
    "check_tangent_frames": "teach.shape_exercises",
    "check_training_step": "teach.loop_exercises",
    "check_ddim_loop": "teach.loop_exercises",
    "check_masked_step": "teach.loop_exercises",
    "image_denoiser": "teach.loop_exercises",
}

#: module-valued public names (namespaces a notebook uses: ``viz.plot_slice``) → the module
_MODULES = {
    "viz": "show.viz",
    "widgets": "show.widgets",
    "viewer": "show.viewer",
    "metrics": "evaluate.metrics",
    "render": "evaluate.render",
    "examples": "examples",
    "box": "data.box",
    "extract": "generate.extract",
    "control": "generate.control",
    "export": "formats.export",
    "mesh_io": "formats.load",
    "lesson2d": "teach.lesson2d",
    "exercises": "teach.exercises",
}

__all__ = sorted(_API) + sorted(_MODULES)


def __getattr__(name: str):
    if name in _API:
        value = getattr(importlib.import_module(f".{_API[name]}", __name__), name)
        globals()[name] = value  # next time without this function
        return value
    if name in _MODULES:
        return importlib.import_module(f".{_MODULES[name]}", __name__)
    raise AttributeError(f"module 'sin3dm_lite' has no attribute '{name}'")


def __dir__():
    return sorted(set(globals()) | set(__all__))
