"""The record of a diversity calibration (:func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity`): the
setting chosen, the settings tried on the way, the goals and the near copy that set them, and the story of why.

A fit keeps it in its ``report.json`` (``report["calibration"]``); :meth:`Calibration.from_dict` reads it back,
records written before the ceiling included, and :meth:`Calibration.story` tells it per goal.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

#: the least LP-F a near copy must keep to set a ceiling: below it the fit does not reproduce its input (a barely
#: trained one keeps no patch) and the goals stay absolute. LP-F, the lenient score: a faithful near copy of walls
#: 2-3 voxels thick on a 32-voxel grid (reconstruction IoU 0.94) keeps LP-IoU 0.02 but LP-F 0.15
MIN_CEILING = 0.1
#: samples that vary less than this are near copies when the calibration chooses (:func:`copy_line`): the diversity
#: the project asks of a run's default samples at the paper's 128 voxels (G-Div ≥ 0.10)
VARIED_G_DIV = 0.10
#: samples count as copies, too, when they vary less than this many times the near copy's G-Div (:func:`copy_line`)
COPY_RATIO = 2.0
#: how the record names the patch scores
SCORE_NAMES = {"lp_iou": "LP-IoU", "lp_fscore": "LP-F"}


def copy_line(near_g_div: float | None) -> float:
    """The G-Div under which the calibration counts samples as near copies: :data:`VARIED_G_DIV`, or
    :data:`COPY_RATIO` times the near copy's G-Div where that is higher (what a near copy varies is the decoder's
    and the noise's jitter, not variation)."""
    near = near_g_div if near_g_div is not None and np.isfinite(near_g_div) else 0.0
    return float(max(VARIED_G_DIV, COPY_RATIO * near))


@dataclass
class Calibration:
    """What :func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity` chose, the settings it tried on the way (in order), and why.

    ``goals`` are the goals the settings were judged by; with a near copy
    (``near_copy``, the ceiling) each is the smaller of ``absolute_goals`` and
    ``relative`` × the near copy's score (the absolute goal where the near copy's
    LP-F is below :data:`MIN_CEILING`). ``at_choice`` holds the smoothed patch
    scores and the samples' G-Div at the chosen setting. A record written
    before the ceiling (absolute goals only) loads with :meth:`from_dict`.
    """

    diversity: float
    goals: dict
    n: int
    resolution: int
    tried: list = field(
        default_factory=list
    )  # [{"diversity", "n", "lp_iou", "lp_fscore", "g_div", "kept", "*_sd", "*_fitted"}]
    kept_goals: bool = False  # False when the choice misses the goals: no setting kept them, or only copies did
    only_copies_kept: bool = False  # only settings whose samples are copies kept the goals (the choice varies)
    near_copy: dict | None = None  # {"diversity", "n", "lp_iou", "lp_fscore", "g_div", "*_sd"}: the ceiling
    absolute_goals: dict | None = None  # the caps (GOALS or the caller's); None: the goals were absolute
    relative: float | dict | None = None  # the share of the near copy's scores, one per goal (one for all: older)
    at_choice: dict | None = (
        None  # {"lp_iou", "lp_fscore", "g_div"} at the chosen setting (smoothed; G-Div between draws)
    )
    g_div_goal: float | None = None  # the diversity requirement the choice is reported against
    supersample: int = 1  # sub-voxels a side per voxel judged (1: the voxel centres; 2: the paper's voxels)
    copy_line: float | None = None  # samples whose G-Div is under this are copies (copy_line); None: older record
    note: str | None = None  # why the choice is not the plain crossing of every goal (copies, or no setting kept LP-F)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, record: dict) -> Calibration:
        """A record from a run's ``report.json`` (``report["calibration"]``), older ones (no ceiling) included."""
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in record.items() if k in known})

    @property
    def missed(self) -> str:
        """Why a choice that misses the goals was taken, in words."""
        return "only copies kept the goals" if self.only_copies_kept else "no setting kept the goals"

    def story(self) -> str:
        """Why this setting, a line per goal: the near copy's score (the ceiling), the goal, the choice."""
        if self.resolution != 128:
            paper = "the paper measures at 128"
        elif self.supersample == 2:
            paper = "as the paper measures"
        else:
            paper = "voxel centres; the paper's voxels pool 2x2x2 sub-voxels"
        grid = f"at {self.resolution} voxels ({paper})"
        chosen = f"chosen {self.diversity:g}" + ("" if self.kept_goals else f" ({self.missed})")
        at = self.at_choice or {}
        if self.near_copy is None:
            goals = ", ".join(f"{SCORE_NAMES.get(k, k)} {v:.2f}" for k, v in self.goals.items())
            return f"absolute goals {goals} {grid} (no near copy scored); {chosen}" + (
                f"\n{self.note}" if self.note else ""
            )
        lines = []
        for key, goal in self.goals.items():
            absolute = (self.absolute_goals or {}).get(key, goal)
            share = self.relative.get(key, 1.0) if isinstance(self.relative, dict) else self.relative
            if self.near_copy["lp_fscore"] < MIN_CEILING:
                why = f"the absolute goal: a near copy of LP-F below {MIN_CEILING:g} sets no ceiling"
            elif goal >= absolute:
                why = f"the absolute goal; {share:.0%} of the near copy is above it"
            elif absolute >= 1:  # no cap (judged at the paper's grid: auto.calibration.default_goals)
                why = f"{share:.0%} of the near copy"
            else:
                why = f"{share:.0%} of the near copy; the absolute {absolute:.2f} is out of its reach"
            there = f", smoothed {at[key]:.2f} there" if key in at else ""
            # since the copy line (issue 61) LP-IoU is a floor, which gives way to LP-F where it would choose copies
            name = SCORE_NAMES.get(key, key) + (" (a floor)" if self.copy_line is not None and key == "lp_iou" else "")
            lines.append(f"{name}: near copy {self.near_copy[key]:.2f}; goal {goal:.2f} ({why}); {chosen}{there}")
        if self.g_div_goal is not None and np.isfinite(at.get("g_div", np.nan)):
            met = "meets" if at["g_div"] >= self.g_div_goal else "is below"
            copies = "" if self.copy_line is None else f"; copies below {self.copy_line:.3f}"
            lines.append(
                f"G-Div at {self.diversity:g}: {at['g_div']:.2f}, which {met} the diversity requirement "
                f"{self.g_div_goal:.2f} (near copy {self.near_copy['g_div']:.2f}{copies})"
            )
        if self.note:
            lines.append(self.note)
        lines.append(f"measured {grid}; near copy = diversity {self.near_copy['diversity']:g}")
        return "\n".join(lines)

    def summary(self) -> str:
        """One line per setting drawn (raw and smoothed patch scores, G-Div), then the choice and why."""
        lines = [
            f"diversity {t['diversity']:.2f}: LP-IoU {t['lp_iou']:.3f} (smoothed {t['lp_iou_fitted']:.3f}) · "
            f"LP-F {t['lp_fscore']:.3f} (smoothed {t['lp_fscore_fitted']:.3f}) · G-Div {t['g_div']:.3f}"
            for t in self.tried
        ]
        if self.near_copy is not None:
            lines.extend(self.story().splitlines())
        if self.near_copy is None and self.note:  # the story above says it where a near copy was drawn
            lines.append(self.note)
        lines.append(f"chosen: {self.diversity:g}" + ("" if self.kept_goals else f" ({self.missed})"))
        return "\n".join(lines)


def mean_by_setting(tried: list[dict], key: str = "g_div") -> dict[float, float]:
    """Each setting drawn and its samples' mean ``key`` score (a setting drawn twice: the mean over its samples)."""
    by_setting: dict[float, list[float]] = {}
    for t in tried:
        by_setting.setdefault(t["diversity"], []).extend([t.get(key, np.nan)] * t["n"])
    return {d: float(np.mean(v)) for d, v in sorted(by_setting.items())}


def g_div_at(tried: list[dict], diversity: float) -> float:
    """The samples' G-Div at ``diversity``: linear between the settings drawn around it."""
    by_setting = mean_by_setting(tried)
    return float(np.interp(diversity, list(by_setting), list(by_setting.values())))


def least_varied(result: Calibration) -> tuple[float | None, dict[float, float]]:
    """The least varied setting drawn whose samples are not copies (None: every one is), and each setting's G-Div."""
    by_setting = mean_by_setting(result.tried)
    varied = [d for d, g in by_setting.items() if not g < (result.copy_line or 0.0)]  # None: an older record
    return (min(varied) if varied else None), by_setting


__all__ = [
    "COPY_RATIO",
    "VARIED_G_DIV",
    "MIN_CEILING",
    "SCORE_NAMES",
    "Calibration",
    "copy_line",
    "g_div_at",
    "least_varied",
    "mean_by_setting",
]
