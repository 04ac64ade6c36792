"""Snapping: the denoiser's estimate of the clean latent pulled towards the input's own latent patches.

Not in the paper. On thin walls and broken tops a sample's estimate of the
clean latent drifts a little from every neighbourhood the input has, and the
walls thicken or break once decoded. Snapping replaces each 7×7 window of the
estimate by its nearest window of the input's latent (patch-nearest-neighbour
generation, as in GPNN, Granot et al. 2022) and averages the overlapping
windows back into texels: the layout stays the sample's, each neighbourhood
becomes one the input has. :func:`snap_hook` makes it the sampler's ``denoised_fn``, on the last tenth
of the noise schedule when ``snap`` > 0
(``sampling.snap``; ``quick`` turns it on by itself for a shape of thin parts).
With ``place`` (``sampling.snap_place``, ``quick`` on thin walls) the search prefers the input's window from
the sample's own place, so that a rare neighbourhood (a window in a wall) comes back where it was rather than
the common one (plain wall) from elsewhere. Why these numbers: docs/thin-parts.md.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

from ..errors import Sin3DMInputError
from ..model.triplane import Triplane

#: distances :func:`snap_to_patches` holds at once (2^20 floats, 4 MB, a slice that stays in the cache; a 128-texel
#: plane has 16,384 windows, whose whole distance matrix would take 1 GB per sample)
SNAP_DISTANCES = 2**20
#: :func:`sample` snaps the estimates of the last tenth of the noise schedule only (t ≤ 0.1·T): on the ruin and
#: the canyon the same G-Div / LP-IoU / LP-F as snapping every step (within 0.03), at 2-5 searches a sample
#: instead of 20-50 (docs/thin-parts.md); earlier estimates are blurry, their nearest windows change nothing
SNAP_LAST = 0.1
#: the windows snapping compares (texels a side): 5×5 kept more of the input's patches than 3×3 at the same G-Div on the
#: ruin and the colonnade, 7×7 more than 5×5 on the ruin (about 0.03 LP-IoU and LP-F at 128 voxels) and as many on
#: the colonnade, for about 0.15 s more a sample (docs/thin-parts.md)
SNAP_PATCH = 7
#: the windows snapping searches for start every SNAP_STRIDE texels in each direction (every second one), and each
#: texel is still the average of 9-16 of them: on the ruin, the coloured ruin, the keep and the colonnade the same
#: G-Div, LP-IoU and LP-F at 128 voxels as searching for every window (within 0.02), in a quarter of the searches
#: (8 snapped samples of the coloured ruin 2.6 s -> 1.0 s; docs/thin-parts.md). At most ``patch // 2 + 1``.
SNAP_STRIDE = 2


def snap_hook(
    snap: float, reference: Triplane | None, timesteps: int, place: float = 0.0
) -> Callable[[Triplane, int], Triplane] | None:
    """Snapping as the sampler's ``denoised_fn(x0, t)`` hook (:func:`sin3dm_lite.model.diffusion.sample`): the
    estimates of the last steps (t ≤ :data:`SNAP_LAST` · ``timesteps``) snapped by :func:`patch_snapper`, the others
    as they are; None (the paper's sampler) for ``snap`` 0. The arguments are checked here, once."""
    snapper = patch_snapper(snap, reference, place=place)
    if snap == 0:
        return None
    below = SNAP_LAST * timesteps
    return lambda x0, t: snapper(x0) if t <= below else x0


def snap_to_patches(
    x: Triplane, reference: Triplane, patch: int = SNAP_PATCH, stride: int | None = None, place: float = 0.0
) -> Triplane:
    """Each plane of ``x`` rebuilt from ``reference``'s patches: every ``patch``×``patch`` window of ``x`` (all
    channels; windows ``stride`` texels apart, :data:`SNAP_STRIDE` by default) is replaced by its nearest (L2)
    window of the same plane of ``reference`` (batch 1, any size, every window a candidate), and the overlapping
    windows are averaged back into texels (borders replicated). The layout stays ``x``'s, each
    neighbourhood becomes one the input has: patch-nearest-neighbour generation (GPNN, Granot et al. 2022)
    applied to the denoiser's estimate of the clean latent (:func:`sample`'s ``snap``). ``place`` > 0 (on a plane of
    ``reference``'s size) adds ``place`` × the squared distance in texels between a window's centre and a candidate's
    to that candidate's distance: among windows nearly as near, the one from the same place wins."""
    return patch_snapper(1.0, reference, patch, stride, place)(x)


def patch_snapper(
    snap: float, reference: Triplane | None, patch: int = SNAP_PATCH, stride: int | None = None, place: float = 0.0
) -> Callable[[Triplane], Triplane]:
    """Snapping: ``x0 ↦ lerp(x0, snap_to_patches(x0, reference), snap)``. :func:`sample` calls it on the predicted
    x0 of its last steps (t ≤ :data:`SNAP_LAST`·T), so with ``snap`` in (0, 1] each ``patch``×``patch``
    neighbourhood of the latent moves towards one the input (``reference``, usually its latent) has while the
    layout stays the sample's; on thin walls it keeps the input's patches at more variation (docs/thin-parts.md). ``snap=0`` is the identity: the paper's sampler.
    ``reference``'s windows are cut once here, not at every step."""
    if not 0.0 <= float(snap) <= 1.0 or (snap > 0 and reference is None):
        raise Sin3DMInputError(f"snap is a share in [0, 1] and needs snap_to (the input's latent); got {snap}")
    if snap == 0:
        return lambda x0: x0
    if reference is None or reference.batch != 1:
        raise Sin3DMInputError(f"snap needs one reference latent, got a batch of {reference and reference.batch}")
    if patch < 1 or patch % 2 == 0:
        raise Sin3DMInputError(f"the snap patch must be an odd number of texels (1, 3, 5, ...), got {patch}")
    pad = patch // 2
    stride = min(SNAP_STRIDE if stride is None else stride, pad + 1)  # wider steps would leave texels uncovered
    if stride < 1:
        raise Sin3DMInputError(f"the snap stride is a whole number of texels, at least 1; got {stride}")
    if not float(place) >= 0:
        raise Sin3DMInputError(f"snap_place weighs a distance in texels: 0 or more, got {place}")

    def windows(t: torch.Tensor, step: int = 1) -> torch.Tensor:  # [B, c·K², windows], one every `step` texels
        return F.unfold(F.pad(t, (pad,) * 4, mode="replicate") if pad else t, patch, stride=step)

    theirs = [windows(r)[0] for r in reference.planes]  # [c·K², h'·w'] per plane, cut once
    # channels that are zero all over the input (a shape of one colour: its 8 texture channels) add the same
    # |ours|² to every candidate's distance, so the search leaves them out: the same windows, found faster
    live = torch.stack([r[0].flatten(1).abs().amax(1) for r in reference.planes]).amax(0) > 0
    keep = bool(live.any()) and not bool(live.all())  # leave channels out (never all of them)
    search = [windows(r[:, live])[0] for r in reference.planes] if keep else theirs
    norms = [(t**2).sum(0) for t in search]

    def plane(p: torch.Tensor, k: int) -> torch.Tensor:
        ref, (h, w) = theirs[k].to(p), p.shape[-2:]
        if ref.shape[0] != p.shape[1] * patch * patch:
            raise Sin3DMInputError(f"snap's reference has other channels than the samples' {p.shape[1]}")
        among = search[k].to(p)
        ours = windows(p[:, live.to(p.device)] if keep else p, stride)  # [B, c·K², windows]
        n_win = ours.shape[-1]
        ours = ours.transpose(1, 2).reshape(-1, among.shape[0])
        rows = max(1, SNAP_DISTANCES // among.shape[1])  # rows of distances at once
        # |ours - theirs|² less |ours|², the same for every candidate; in slices so memory stays bounded
        near = place > 0 and (h, w) == tuple(reference.planes[k].shape[-2:])  # the same place means something
        dist = (
            torch.addmm(
                norms[k].to(p) + (_apart(i, len(o), h, w, stride, p) * place if near else 0), o, among, alpha=-2
            )
            for i, o in zip(range(0, len(ours), rows), ours.split(rows))
        )
        nearest = torch.cat([d.argmin(-1) for d in dist]).view(len(p), n_win)
        chosen = ref[:, nearest].permute(1, 0, 2)  # [B, c·K², windows]
        size = (h + 2 * pad, w + 2 * pad)
        covers = F.fold(chosen.new_ones(1, patch * patch, n_win), size, patch, stride=stride)  # windows per texel
        votes = F.fold(chosen, size, patch, stride=stride) / covers
        return votes[:, :, pad : pad + h, pad : pad + w]

    def snapped(x0: Triplane) -> Triplane:
        pulled = Triplane(*(plane(p, k) for k, p in enumerate(x0.planes)))
        return x0.zip_map(pulled, lambda a, b: torch.lerp(a, b, float(snap)))

    return snapped


def _apart(first: int, n: int, h: int, w: int, stride: int, like: torch.Tensor) -> torch.Tensor:
    """Squared distances in texels ``[n, h·w]`` between the centres of the windows ``first`` … ``first + n - 1``
    of a batch of ``h``×``w`` planes (windows ``stride`` texels apart, row by row, plane after plane) and every
    window of a reference plane of the same size (one a texel, row by row)."""
    across = len(range(0, w, stride))
    index = torch.arange(first, first + n, device=like.device) % (len(range(0, h, stride)) * across)
    y, x = (index // across * stride).to(like.dtype), (index % across * stride).to(like.dtype)
    ry = torch.arange(h, device=like.device, dtype=like.dtype).repeat_interleave(w)
    rx = torch.arange(w, device=like.device, dtype=like.dtype).repeat(h)
    return (y[:, None] - ry) ** 2 + (x[:, None] - rx) ** 2


__all__ = ["SNAP_DISTANCES", "SNAP_LAST", "SNAP_PATCH", "SNAP_STRIDE", "patch_snapper", "snap_to_patches"]
