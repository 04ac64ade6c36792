"""The paper's evaluation in one namespace (``from sin3dm_lite import metrics``): the geometry metrics of
:mod:`~sin3dm_lite.evaluate.geometry` and :mod:`~sin3dm_lite.evaluate.patches`, the texture metrics of
:mod:`~sin3dm_lite.evaluate.texture` (no weights) and :mod:`~sin3dm_lite.evaluate.features` (SIFID, LPIPS), and
here :func:`texture_scores` and :func:`results_table` (evaluations side by side).
"""

from __future__ import annotations

from ..errors import Sin3DMInputError
from .features import (  # noqa: F401
    ALEXNET_FILE,
    INCEPTION_FILES,
    LPIPS_FILE,
    SSFID_UNAVAILABLE,
    BasicConv2d,
    FeatureNets,
    InceptionStem,
    LPIPSAlex,
    frechet_distance,
    load_feature_weights,
    lpips,
    sifid,
)
from .geometry import (  # noqa: F401
    PAPER_SUPERSAMPLE,
    any_inside,
    check_same_grid,
    g_div,
    g_div_by_layer,
    geometry_scores,
    input_occupancy,
    iou,
    pairwise_iou,
    reconstruction_iou,
    reconstruction_metrics,
    variation_scores,
    voxelize,
)
from .patches import (  # noqa: F401
    extract_patches,
    lp_fscore,
    lp_iou,
    lp_misses_by_band,
    lp_scores,
    lp_scores_any_offset,
    patch_matches,
)
from .texture import (  # noqa: F401
    BACKGROUND,
    colour_distance,
    degraded,
    foreground,
    patch_swd,
    render_div,
    t_div,
    t_qual,
)

#: the metrics of ``Sin3DM.evaluate``: (key, the paper's name, which way is better), in the order tables show them
METRICS = (
    ("g_div", "G-Div", "higher = more diverse shapes"),
    ("lp_iou", "LP-IoU", "higher = local geometry like the input's"),
    ("lp_fscore", "LP-F", "higher = local geometry like the input's"),
    ("lp_iou_any_offset", "not in the paper", "LP-IoU against the input's patches at every voxel (moved pieces count)"),
    (
        "lp_fscore_any_offset",
        "not in the paper",
        "LP-F against the input's patches at every voxel (moved pieces count)",
    ),
    ("iou_to_input", "not in the paper", "near 1 = copies of the input"),
    ("ssfid", "G-Qual (SSFID)", "lower = better"),
    ("patch_swd", "T-Qual stand-in", "lower = texture patches like the input's (weight-free, not SIFID)"),
    ("render_div", "T-Div stand-in", "higher = more varied renders (weight-free, not LPIPS)"),
    ("sifid", "T-Qual (SIFID)", "lower = better"),
    ("lpips", "T-Div (LPIPS)", "higher = more diverse textures"),
)


def results_table(columns: dict, digits: int = 3) -> str:
    """Several evaluations side by side as a text table: one row per metric of :data:`METRICS`, one column each.

    ``columns`` maps a label to a ``Sin3DM.evaluate`` result (or its ``"metrics"``); a metric not computed shows
    as ``-``.
    """
    if not columns:
        raise Sin3DMInputError("results_table needs at least one column")
    values = {label: r.get("metrics", r) for label, r in columns.items()}
    width = max(10, digits + 4, *(len(label) for label in values))
    keys = max(len(key) for key, _, _ in METRICS)
    lines = [f"{'metric':{keys}s} " + " ".join(f"{label:>{width}s}" for label in values) + "  paper's name: meaning"]
    for key, paper, meaning in METRICS:
        cells = ["-" if m.get(key) is None else f"{m[key]:.{digits}f}" for m in values.values()]
        lines.append(f"{key:{keys}s} " + " ".join(f"{c:>{width}s}" for c in cells) + f"  {paper}: {meaning}")
    return "\n".join(lines)


def texture_scores(reference_views, sample_views, nets: FeatureNets | None = None) -> dict:
    """The texture metrics of renders, view by view: ``patch_swd`` and ``render_div`` always, ``sifid`` and
    ``lpips`` (the paper's T-Qual and T-Div) with ``nets``; the diversities are None for one sample."""
    sample_views = list(sample_views)
    several = len(sample_views) > 1
    out = {
        "patch_swd": t_qual(reference_views, sample_views, patch_swd),
        "render_div": render_div(sample_views) if several else None,
    }
    if nets is not None:
        out["sifid"] = t_qual(reference_views, sample_views, lambda x, y: sifid(x, y, nets))
        out["lpips"] = t_div(sample_views, lambda x, y: lpips(x, y, nets)) if several else None
    return out


__all__ = [
    "FeatureNets",
    "check_same_grid",
    "InceptionStem",
    "LPIPSAlex",
    "SSFID_UNAVAILABLE",
    "METRICS",
    "colour_distance",
    "degraded",
    "extract_patches",
    "foreground",
    "frechet_distance",
    "geometry_scores",
    "load_feature_weights",
    "lpips",
    "patch_swd",
    "render_div",
    "sifid",
    "t_div",
    "t_qual",
    "texture_scores",
    "g_div",
    "input_occupancy",
    "iou",
    "lp_fscore",
    "lp_iou",
    "lp_misses_by_band",
    "lp_scores",
    "lp_scores_any_offset",
    "pairwise_iou",
    "patch_matches",
    "reconstruction_metrics",
    "reconstruction_iou",
    "results_table",
    "variation_scores",
    "voxelize",
    "any_inside",
    "PAPER_SUPERSAMPLE",
]
