"""Exercise (notebook 07): LP-IoU's patch match, each generated patch's best IoU among the input's patches."""

import numpy as np


def best_patch_iou(gen, ref):
    """``gen (m, P)``, ``ref (n, P)`` bool patches → ``(m,)``: max over r of |g ∩ r| / |g ∪ r|."""
    g, r = gen.astype(np.float64), ref.astype(np.float64)
    inter = g @ r.T  # (m, n) voxels in both
    union = g.sum(1)[:, None] + r.sum(1)[None, :] - inter
    return (inter / union).max(1)
