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

#: module → the public names it defines
_NAMES = {
    # facade and settings
    "pipeline": "Sin3DM open_run",
    "app.sampling": "Samples",
    "data.source": "resolve_mesh",
    "data.config": "Config",
    "presets": "get_preset notebook_preset fast_mode",
    "app.pretrained": "pretrained_path shipped_names shipped_examples",
    "errors": "Sin3DMInputError",
    "app.device": "get_device count_parameters",
    # data
    "examples": "DEFAULT_EXAMPLE build_example list_examples write_example",
    "data.mesh": "TexturedMesh Material Normalization tangent_frames",
    "formats.load": "load_mesh load_any",
    "data.box": "grid_shape margin_scale",
    "data.grid": "ShapeGrid PBR_CHANNELS mesh_to_grid load_grid save_grid",
    # model
    "model.triplane": "Triplane",
    "model.autoencoder": "TriplaneEncoder TriplaneDecoder AutoencoderTrainer grid_tensor",
    "model.decode": "decode_grid prepare query_points reconstructed_grid",
    "model.unet": "TriplaneUNet TriplaneConv rollout_parts block_layout",
    "teach.receptive_field": "receptive_field analytic_receptive_field layer_walk layers_receptive_field",
    "model.schedule": "NoiseSchedule ddim_timesteps",
    "model.diffusion": "DiffusionTrainer sample predict_clean diffusion_loss triplane_mse",
    # generate
    "generate.extract": "extract_mesh marching_cubes",
    "generate.bake": "pbr_maps",
    "formats.export": "export_mesh",
    # eval
    "evaluate.metrics": (
        "reconstruction_metrics voxelize input_occupancy iou g_div lp_scores geometry_scores patch_swd render_div "
        "texture_scores load_feature_weights sifid lpips"
    ),
    "evaluate.ssfid": "ssfid load_ssfid_classifier",
    "evaluate.calibrate": "calibrate_diversity",
    "evaluate.calibration_record": "Calibration",
    # exercises: write a piece of the method, check it against the library
    "teach.checking": "ExerciseError",
    "teach.exercises": (
        "check_q_sample check_ddpm_posterior check_ddim_step check_triplane_lookup check_receptive_field "
        "check_rollout check_best_patch_iou"
    ),
    "teach.shape_exercises": "check_grid_box check_retarget check_regenerate_mask check_tangent_frames",
    "teach.loop_exercises": "check_training_step check_ddim_loop check_masked_step image_denoiser",
}
#: public name → module that defines it
_API = {name: module for module, names in _NAMES.items() for name in names.split()}

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
