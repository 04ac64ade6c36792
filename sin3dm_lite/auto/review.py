"""A fit's last look, after the paper's stages: do the samples from pure noise vary at all, and where the chosen
diversity gives near copies, how to judge it as the paper measures.

Not in the paper: :mod:`sin3dm_lite.app.fitting` calls :func:`review_fit` once, between training and saving. The
paper's receptive-field ablation says why it can fail: too large a field for the shape "overfits to the input
example and is unable to produce variations"; no diversity setting then varies it, and the fit says so.
"""

from __future__ import annotations

import warnings
from shlex import quote

from ..evaluate.calibration_record import VARIED_G_DIV
from .fit_policy import copies_warning, from_noise_distance, g_div_at_one


def copies_check(model) -> tuple[float, str | None]:
    """How far the samples from pure noise lie from the input's latent (:func:`from_noise_distance`) and, with the
    G-Div of the calibration's samples at diversity 1, the warning :func:`copies_warning` gives (None where they
    vary)."""
    distance = from_noise_distance(model, seed=model.config.seed)
    return distance, copies_warning(model.config, distance, g_div_at_one(model.report.get("calibration")))


def paper_grid_hint(calibration: dict | None, run=None) -> str | None:
    """What a fit says when its calibration, judged on the training grid by the voxel centres, chose near copies
    (G-Div under :data:`VARIED_G_DIV` at the choice), else None: judged as the paper measures (128 voxels, a voxel
    solid where any of its 2³ sub-voxels is), thin walls keep more of their patches and the choice is more varied,
    in a few minutes more (docs/calibration.md)."""
    cal = calibration or {}
    g_div = (cal.get("at_choice") or {}).get("g_div")
    if g_div is None or not g_div < VARIED_G_DIV or cal.get("resolution", 128) >= 128:
        return None
    how = f"sin3dm-lite calibrate {quote(str(run))} --resolution 128" if run else "model.calibrate(resolution=128)"
    return (
        f"[fit] the chosen diversity {cal.get('diversity', 0):g} gives near copies (G-Div {g_div:.3f}) as judged on "
        f"the {cal.get('resolution')}-voxel training grid, where a thin wall moved by a fraction of a voxel loses its "
        "patches; judged as the paper measures (128 voxels), the choice is often more varied, in a few minutes more: "
        f"{how}"
    )


def review_fit(model, calibrated: bool, say=print, run=None) -> None:
    """The trained ``model`` looked at once more: where the fit ``calibrated`` (a few samples, about a second), whether
    its samples from pure noise are copies (the distance lands in its report, the verdict in a warning), and how to
    judge a choice of near copies as the paper measures (:func:`paper_grid_hint`, said)."""
    if not calibrated:
        return
    if (hint := paper_grid_hint(model.report.get("calibration"), run)) is not None:
        say(hint)
    distance, warning = copies_check(model)
    model.report["from_noise_distance"] = distance
    if warning is not None:
        # stacklevel: this function, FitRun.stages, fitting.fit, Sin3DM.fit, and the code that called it
        warnings.warn(warning, stacklevel=5)


__all__ = ["copies_check", "paper_grid_hint", "review_fit"]
