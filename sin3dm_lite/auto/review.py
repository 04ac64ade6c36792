"""A fit's last look, after the paper's stages: what the application decides about the trained model (not in the
paper; :mod:`sin3dm_lite.app.fitting` calls :func:`review_fit` once, between training and saving).

* the copies check: do the samples from pure noise vary at all (:func:`copies_check`)? a warning when not;
* the rollout switch: a plain denoiser whose calibration keeps the input's patches even from pure noise is trained
  again with the cross-plane rollout (the shape's layout varies little whatever the knob, so the rollout costs no
  variation), and checked again;
* the hints: the rollout where the preset has no switch, a finer calibration grid for a switched fit.
"""

from __future__ import annotations

import warnings

from .fit_policy import (
    calibration_grid_hint,
    copies_warning,
    from_noise_distance,
    g_div_at_one,
    keeps_goals_from_noise,
    rollout_hint,
)


def copies_check(model, thin_parts: dict | None) -> tuple[float, str | None]:
    """How far the samples from pure noise lie from the input's latent (:func:`from_noise_distance`) and, with the
    G-Div of the calibration's samples at diversity 1, the warning :func:`copies_warning` gives (None where they
    vary)."""
    cfg = model.config
    distance = from_noise_distance(model, seed=cfg.seed)
    return distance, copies_warning(cfg, distance, thin_parts, g_div_at_one(model.report.get("calibration")))


def review_fit(fit, model, history, trained: tuple, rollout: dict | None, thin_parts: dict | None):
    """The trained ``model`` looked at once more by the fit ``fit`` (an :class:`app.fitting.FitRun`: its
    ``switch_to_rollout``, ``timings``, ``say`` and ``run``); ``trained`` is ``(grid, h0, ae, metrics, base)``.
    Returns the model and its denoiser's history (both new where the rollout switch trained again)."""
    cfg = model.config  # the narrower denoiser's, where the wider field copied the shape
    calibration = model.report.get("calibration")
    # a calibrated fit: do its samples vary at all? (a few samples, about a second). Samples that copy the
    # input keep its patches from pure noise too, but the rollout would only hold the layout tighter
    distance, warning = copies_check(model, thin_parts) if cfg.sampling.calibrate else (None, None)
    if warning is None and rollout is None and cfg.rollout_switch and keeps_goals_from_noise(cfg, calibration):
        grid, h0, ae, metrics, base = trained
        cfg, model, history, rollout = fit.switch_to_rollout(cfg, grid, h0, ae, metrics, base, calibration)
        distance, warning = copies_check(model, thin_parts)  # the new denoiser's
    if rollout is not None:
        fit.timings["rollout_switch_s"] = rollout["plain_s"]
    hint = None if cfg.rollout_switch or warning else rollout_hint(cfg, calibration)
    if hint is not None:
        model.report["rollout_hint"] = hint
        fit.say(hint)
    if (hint := calibration_grid_hint(thin_parts, model.report.get("calibration"), fit.run)) is not None:
        fit.say(hint)
    if distance is not None:
        model.report["from_noise_distance"] = distance
        if warning is not None:
            # stacklevel: this function, FitRun.stages, fitting.fit, Sin3DM.fit, and the code that called it
            warnings.warn(warning, stacklevel=5)
    return model, history


__all__ = ["copies_check", "review_fit"]
