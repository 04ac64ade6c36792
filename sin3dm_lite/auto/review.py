"""A fit's last look, after the paper's stages: do the samples from pure noise vary at all?

Not in the paper: :mod:`sin3dm_lite.app.fitting` calls :func:`review_fit` once, between training and saving. The
paper's receptive-field ablation says why it can fail: too large a field for the shape "overfits to the input
example and is unable to produce variations"; no diversity setting then varies it, and the fit says so.
"""

from __future__ import annotations

import warnings

from .fit_policy import copies_warning, from_noise_distance, g_div_at_one


def copies_check(model) -> tuple[float, str | None]:
    """How far the samples from pure noise lie from the input's latent (:func:`from_noise_distance`) and, with the
    G-Div of the calibration's samples at diversity 1, the warning :func:`copies_warning` gives (None where they
    vary)."""
    distance = from_noise_distance(model, seed=model.config.seed)
    return distance, copies_warning(model.config, distance, g_div_at_one(model.report.get("calibration")))


def review_fit(model, calibrated: bool) -> None:
    """The trained ``model`` looked at once more: where the fit ``calibrated`` (a few samples, about a second), whether
    its samples from pure noise are copies; the distance lands in its report, the verdict in a warning."""
    if not calibrated:
        return
    distance, warning = copies_check(model)
    model.report["from_noise_distance"] = distance
    if warning is not None:
        # stacklevel: this function, FitRun.stages, fitting.fit, Sin3DM.fit, and the code that called it
        warnings.warn(warning, stacklevel=5)


__all__ = ["copies_check", "review_fit"]
