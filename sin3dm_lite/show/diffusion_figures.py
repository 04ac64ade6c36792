"""Figures of diffusion: the denoising steps (x_t and predicted x0), training losses, the noise schedule."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from ..model.triplane import PLANES, Triplane, pca_basis, pca_project, plane_to_image
from .figures import as_numpy, new_figure, panel_height, show_image


def plot_denoising(
    intermediates: Sequence[dict],
    plane: str = "xy",
    channels: str | int = "pca",
    batch: int = 0,
    reference: Triplane | None = None,
) -> Figure:
    """The reverse process: ``x_t`` (top row) and the predicted ``x0`` (bottom row) at each recorded step.

    ``intermediates`` is the sampler's list of ``{"step", "t", "x_t", "x0"}`` dicts (sample ``batch`` shown).
    With ``channels="pca"`` every panel uses *one* PCA basis, fitted on ``reference``'s plane (default: the
    final ``x0``), so a colour means the same feature direction in every column.
    """
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {PLANES}, got {plane!r}")
    if len(intermediates) == 0:
        raise ValueError("intermediates is empty: ask the sampler to record its steps")
    k = PLANES.index(plane)

    def get(tp: Triplane) -> np.ndarray:
        return as_numpy(tp.planes[k][batch])

    if channels == "pca":
        mean, basis = pca_basis(get(reference if reference is not None else intermediates[-1]["x0"]))
        to_image = lambda p: pca_project(p, mean, basis)
    else:
        to_image = lambda p: plane_to_image(p, channels)
    n = len(intermediates)
    a, b = get(intermediates[0]["x_t"]).shape[-2:]  # drawn with a → and b ↑
    fig = new_figure(max(2.0 * n, 3.0), 2 * panel_height(2.0, b / a) + 0.3)
    panels = fig.subplots(2, n, squeeze=False)
    for c, entry in enumerate(intermediates):
        for r, key in enumerate(("x_t", "x0")):
            ax = panels[r, c]
            show_image(ax, to_image(get(entry[key])))
            ax.set(xticks=[], yticks=[])
        panels[0, c].set_title(f"t = {int(entry['t'])}", fontsize=9)
    panels[0, 0].set_ylabel(f"x_t ({plane})")
    panels[1, 0].set_ylabel("predicted x0")
    return fig


def moving_average(values: Sequence[float], window: int) -> np.ndarray:
    """Mean of each run of ``window`` consecutive values (length ``len(values) - window + 1``)."""
    v = np.asarray(values, np.float64)
    window = max(1, min(int(window), len(v)))
    c = np.cumsum(np.insert(v, 0, 0.0))
    return (c[window:] - c[:-window]) / window


def plot_losses(history, log: bool = True, title: str | None = None, window: int | None = None) -> Figure:
    """Training curves: each series raw (thin, faint) and its moving average (thick).

    ``history`` is a list of floats or a dict ``name -> list of floats``; ``window`` defaults to 1/50 of the
    run. The y axis is logarithmic when ``log`` and every value is positive.
    """
    series = history if isinstance(history, dict) else {"loss": history}
    fig = new_figure(6.0, 3.6)
    ax = fig.subplots()
    all_positive = True
    for k, (name, values) in enumerate(series.items()):
        v = np.asarray([float(x) for x in values], np.float64)
        if len(v) == 0:
            continue
        all_positive &= bool(np.all(v > 0))
        steps = np.arange(len(v))
        ax.plot(steps, v, color=f"C{k}", lw=0.6, alpha=0.35)
        w = window or max(1, len(v) // 50)
        ma = moving_average(v, w)
        ax.plot(steps[w - 1 :] if w <= len(v) else steps[-1:], ma, color=f"C{k}", lw=2.0, label=f"{name} (avg {w})")
    if log and all_positive:
        ax.set_yscale("log")
    ax.set(xlabel="step", ylabel="loss")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return fig


def plot_schedule(alphas_cumprod, betas) -> Figure:
    """The noise schedule: ``β_t`` (left) and ``ᾱ_t``, ``√ᾱ_t`` (signal), ``√(1-ᾱ_t)`` (noise) (right)."""
    ac = as_numpy(alphas_cumprod).astype(np.float64)
    b = as_numpy(betas).astype(np.float64)
    t = np.arange(len(ac))
    fig = new_figure(9.0, 3.4)
    left, right = fig.subplots(1, 2)
    left.plot(np.arange(len(b)), b, color="C3")
    left.set_title("β_t", fontsize=10)
    left.set_xlabel("t")
    right.plot(t, ac, label="ᾱ_t", color="C0")
    right.plot(t, np.sqrt(ac), label="√ᾱ_t (signal)", color="C2")
    right.plot(t, np.sqrt(1 - ac), label="√(1-ᾱ_t) (noise)", color="C1")
    right.set_xlabel("t")
    right.set_title("x_t = √ᾱ_t x0 + √(1-ᾱ_t) ε", fontsize=10)
    right.legend(fontsize=8)
    for ax in (left, right):
        ax.grid(alpha=0.3)
    return fig
