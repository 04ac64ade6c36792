"""A fit's last look, not in the paper: do the samples from pure noise vary at all (too large a receptive field
"overfits to the input example", the paper's ablation says), and where the chosen diversity gives near copies, how
to judge it as the paper measures. :mod:`sin3dm_lite.app.fitting` calls :func:`review_fit` before saving.
"""

from __future__ import annotations

import warnings
from shlex import quote

from ..evaluate.calibration_record import VARIED_G_DIV
from .fit_policy import copies_warning, from_noise_distance, g_div_at_one


def paper_grid_hint(calibration: dict | None, run=None) -> str | None:
    """What a fit says when its calibration, judged on a training grid coarser than 128 voxels, chose near copies
    (G-Div under :data:`VARIED_G_DIV` at the choice), else None: judged as the paper measures, thin walls keep more
    of their patches."""
    cal = calibration or {}
    g_div = (cal.get("at_choice") or {}).get("g_div")
    if g_div is None or not g_div < VARIED_G_DIV or cal.get("resolution", 128) >= 128:
        return None
    how = f"sin3dm-lite calibrate {quote(str(run))} --resolution 128" if run else "model.calibrate(resolution=128)"
    return (
        f"[fit] the chosen diversity {cal.get('diversity', 0):g} gives near copies (G-Div {g_div:.3f}) as judged on "
        f"the {cal.get('resolution')}-voxel training grid, where a surface moved by a fraction of a voxel loses its "
        "patches; judged as the paper measures (128 voxels), the choice is often more varied, in a few minutes more: "
        f"{how}"
    )


def review_fit(model, calibrated: bool, say=print, run=None) -> None:
    """The trained ``model`` looked at once more where the fit ``calibrated``: :func:`paper_grid_hint`, said, and
    whether its samples from pure noise are copies (the distance lands in its report, the verdict in a warning)."""
    if not calibrated:
        return
    if (hint := paper_grid_hint(model.report.get("calibration"), run)) is not None:
        say(hint)
    distance = from_noise_distance(model, seed=model.config.seed)
    tried = model.report.get("narrower_field", {}).get("kept") is False  # a narrower field was trained, not kept
    warning = copies_warning(model.config, distance, g_div_at_one(model.report.get("calibration")), tried)
    model.report["from_noise_distance"] = distance
    if warning is not None:
        # stacklevel: this function, FitRun.stages, fitting.fit, Sin3DM.fit, and the code that called it
        warnings.warn(warning, stacklevel=5)


__all__ = ["paper_grid_hint", "review_fit"]
