"""Exercise (notebook 06): the three keep masks of a local edit."""

import numpy as np


def regenerate_mask(resolution, box, border):
    """``resolution`` (X, Y, Z), ``box`` two corners in [0, 1], ``border`` texels of ramp → keep masks (xy, xz, yz)."""
    profiles, spans = [], []
    for lo, hi, n in zip(box[0], box[1], resolution):
        a, b = round(lo * n), round(hi * n)  # the box's texels along this axis: a .. b-1
        spans.append(a == 0 and b == n)
        centre = np.arange(n) + 0.5
        d = np.maximum(np.maximum(a - centre, centre - b), 0)  # texels outside the box's range
        profiles.append((d == 0).astype(float) if border <= 0 else np.clip(1 - d / border, 0, 1))
    masks = []
    for p, q in ((0, 1), (0, 2), (1, 2)):  # xy, xz, yz
        third = 3 - p - q
        free = np.outer(profiles[p], profiles[q]) if spans[third] else np.zeros((resolution[p], resolution[q]))
        masks.append(1 - free)  # a plane is freed only if the box spans the whole axis across it
    return tuple(masks)
