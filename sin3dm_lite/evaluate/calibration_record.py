"""The record of a diversity calibration (:func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity`): the
setting chosen, the settings tried, the goals and the near copy that set them, and why. A fit keeps it in its
``report.json`` (``report["calibration"]``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

#: the least LP-F a near copy must keep to set a ceiling: below it the fit does not reproduce its input and the
#: goals stay absolute (LP-F, the lenient score: thin walls on a coarse grid keep almost no LP-IoU)
MIN_CEILING = 0.1
#: samples that vary less than this are near copies (:func:`copy_line`): the diversity asked of a run's defaults
VARIED_G_DIV = 0.10
#: samples count as copies, too, when they vary less than this many times the near copy's G-Div
COPY_RATIO = 2.0
#: how the record names the patch scores
SCORE_NAMES = {"lp_iou": "LP-IoU", "lp_fscore": "LP-F"}


def copy_line(near_g_div: float | None) -> float:
    """The G-Div under which samples count as near copies: :data:`VARIED_G_DIV`, or :data:`COPY_RATIO` times the
    near copy's G-Div where that is higher (a near copy's G-Div is jitter, not variation)."""
    near = near_g_div if near_g_div is not None and np.isfinite(near_g_div) else 0.0
    return float(max(VARIED_G_DIV, COPY_RATIO * near))


@dataclass
class Calibration:
    """What :func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity` chose, the settings it tried (in order), and
    why. ``goals`` judged the settings: with a near copy, each is the smaller of ``absolute_goals`` and ``relative``
    × the near copy's score."""

    diversity: float
    goals: dict
    n: int
    resolution: int
    tried: list = field(default_factory=list)  # rows {"diversity", "n", "lp_iou", "lp_fscore", "g_div", "kept", …}
    kept_goals: bool = False  # False: no setting kept the goals, or only copies did
    only_copies_kept: bool = False
    near_copy: dict | None = None  # the near copy's row: the ceiling
    absolute_goals: dict | None = None  # the caps; None: the goals were absolute
    relative: float | dict | None = None  # the share of the near copy's scores, per goal (one for all: older)
    at_choice: dict | None = None  # {"lp_iou", "lp_fscore", "g_div"} at the chosen setting (smoothed)
    g_div_goal: float | None = None  # the diversity requirement the choice is reported against
    supersample: int = 1  # sub-voxels a side per voxel judged (1: the voxel centres; 2: the paper's voxels)
    copy_line: float | None = None  # samples whose G-Div is under this are copies; None: an older record
    note: str | None = None  # why the choice is not the plain crossing of every goal

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, record: dict) -> Calibration:
        """A record from a run's ``report.json`` (``report["calibration"]``); unknown keys are ignored."""
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
            elif absolute >= 1:  # no cap
                why = f"{share:.0%} of the near copy"
            else:
                why = f"{share:.0%} of the near copy; the absolute {absolute:.2f} is out of its reach"
            there = f", smoothed {at[key]:.2f} there" if key in at else ""
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
        elif self.note:  # the story says it where a near copy was drawn
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
    varied = [d for d, g in by_setting.items() if not g < (result.copy_line or 0.0)]
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
