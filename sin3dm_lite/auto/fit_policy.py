"""What a fit says about its input and settings, beyond the paper: which variant to fit (:func:`choose_pbr`), a turn
that lines the shape's walls up with the triplane's axes (:func:`choose_turn`), a reconstruction too poor for useful
samples (:func:`warn_if_poor`), samples from pure noise that copy the input: a second denoiser with a narrower field
(:func:`narrower_field`), else a warning (:func:`copies_warning`)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..data.config import Config
from ..data.mesh import TexturedMesh
from ..evaluate.calibration_record import VARIED_G_DIV
from ..presets import PRESETS

MIN_IOU = 0.9  # fit warns below this reconstruction occupancy IoU ...
MIN_PSNR = 18.0  # ... or this colour PSNR (dB): an RMS colour error above 12.6 %
#: walls that agree on two directions at right angles more than this (:func:`wall_directions`: 0 round, 1 a box) ...
WALLS_AGREE = 0.5
#: ... and lie at least this many degrees off x and z are turned along them
LEAST_TURN = 2.0


def refit_advice(cfg: Config, setting: str, value, also: str = "") -> str:
    """ "fit again with SETTING=VALUE (CLI: --set ...; Python: ...)" for the run's ``cfg``."""
    base = cfg.name.split("+")[0]
    preset = f"preset=get_preset('{base}')" if base in PRESETS else "your Config"
    python = f"{preset}.updated(**{{'{setting}': {value!r}}})"
    cli = str(value).lower() if isinstance(value, bool) else value
    return f"fit again with {setting}={cli}{also} (CLI: --set {setting}={cli}; Python: {python})"


def warn_if_poor(rec: dict, cfg: Config) -> None:
    """Warn when the autoencoder's reconstruction is too poor for useful samples, with the likely cause and the
    setting of the run's ``cfg`` to fit again with (colour: more steps; occupancy: more steps or a finer grid). The
    colour is judged at the surface, where a baked texture reads it (``color_psnr_surface``, else ``color_psnr``)."""
    iou, steps = rec.get("occupancy_iou"), cfg.autoencoder.steps
    psnr = rec.get("color_psnr_surface", rec.get("color_psnr"))
    if iou is not None and iou < MIN_IOU:
        finer = f" or grid.resolution={8 * round(1.5 * cfg.grid.resolution / 8)}"
        warnings.warn(
            f"low reconstruction quality: occupancy IoU {iou:.3f} < {MIN_IOU} (likely cause: too few "
            f"autoencoder steps or a grid too coarse for thin parts); "
            f"{refit_advice(cfg, 'autoencoder.steps', 2 * steps, finer)}",
            stacklevel=3,
        )
    if psnr is not None and psnr < MIN_PSNR:
        doublings = min(3, math.ceil((MIN_PSNR - psnr) / 1.3))  # doublings that make up the missing dB, at most 3
        warnings.warn(
            f"low reconstruction quality: colour PSNR {psnr:.2f} dB at the surface < {MIN_PSNR:.0f} dB (likely cause: too "
            "few autoencoder steps for this texture's detail: each doubling gave about 1.3 dB on a "
            f"two-texture mesh, and doubles the autoencoder's time); "
            f"{refit_advice(cfg, 'autoencoder.steps', steps * 2**doublings)}",
            stacklevel=3,
        )


#: samples from pure noise whose latents lie closer to the input's than this (:func:`from_noise_distance`) may be
#: copies; where the fit calibrated, the G-Div of its samples at diversity 1 decides instead
COPIES_DISTANCE = 0.07
#: the share of its steps that :func:`copies_warning` advises a denoiser to train for where one ResBlock fewer is not
#: the way (docs/lab-notes.md: on the narrow round tower that one ResBlock fewer tore, this share varied it on the
#: Xeon; on two more round ones it did not reach every goal)
SHORTER_SHARE = 0.75
#: the fewest ResBlocks a denoiser has for :func:`narrower_field` to train one with one fewer (the finer presets' 4;
#: of six narrow towers whose samples from pure noise were copies, 3 varied the square ones and tore the round ones,
#: docs/lab-notes.md)
NARROWER_FROM = 3
#: the second denoiser's calibration against the first's time: the first ends at diversity 1, whose copies keep the
#: goals; the second walks down from a torn 1 (docs/lab-notes.md)
NARROWER_CALIBRATION = 2.5


def from_noise_distance(model, n: int = 4, seed: int = 0) -> float:
    """How far ``n`` samples from pure noise (diversity 1) lie from the input's latent: their mean squared
    difference over the input latent's variance, all channels (0: copies). Colour counts: samples that keep the
    geometry but reshuffle the colours are no copies."""
    planes = model.sample(n, seed=seed, diversity=1.0, progress=False).triplane.planes
    ref = model.latent.planes
    diff = sum(float(((p - r.to(p)) ** 2).mean()) for p, r in zip(planes, ref))
    spread = sum(float(((r - r.mean()) ** 2).mean()) for r in ref)
    return diff / max(spread, 1e-12)


def g_div_at_one(calibration: dict | None) -> float | None:
    """The mean G-Div of a calibration's samples at diversity 1 (on the grid it judged; None if it drew none)."""
    rows = [t["g_div"] for t in (calibration or {}).get("tried", []) if t.get("diversity") == 1.0 and "g_div" in t]
    return float(sum(rows) / len(rows)) if rows else None


def narrower_field(cfg: Config, calibration: dict | None) -> Config | None:
    """The config of a second denoiser where a fit's calibration found copies even among its samples from pure noise
    (G-Div at diversity 1 under :data:`VARIED_G_DIV`, as :func:`copies_warning` judges): one ResBlock fewer, a field 4 texels narrower (the paper's
    ablation: too large a field "overfits to the input example"). None where those samples vary, or where the
    denoiser has fewer than :data:`NARROWER_FROM` ResBlocks."""
    g_div = g_div_at_one(calibration)
    if g_div is None or g_div >= VARIED_G_DIV or cfg.diffusion.n_resblocks < NARROWER_FROM:
        return None
    return cfg.updated(**{"diffusion.n_resblocks": cfg.diffusion.n_resblocks - 1})


def narrower_kept(second: dict, first: dict) -> bool:
    """Whether a second denoiser's calibration (:func:`narrower_field`) replaces the first's: it kept the goals and
    its samples at its chosen setting vary more (G-Div) than the first's at theirs. A calibration that ends at
    diversity 1 keeps the goals even where its samples are copies, so a second that copies as the first did is no
    gain and the first stays."""

    def g_div(calibration: dict) -> float:
        return float((calibration.get("at_choice") or {}).get("g_div", 0.0))

    return bool(second.get("kept_goals")) and g_div(second) > g_div(first)


def copies_warning(
    cfg: Config, distance: float, g_div: float | None = None, narrower_tried: bool = False
) -> str | None:
    """What a fit warns when even its samples from pure noise are (near) copies of the input, else None: the
    calibration's samples at diversity 1 vary less than G-Div :data:`VARIED_G_DIV` or, without them, their latents
    lie near the input's (:data:`COPIES_DISTANCE`). The denoiser's field then holds the shape's whole layout (the
    paper's "too large a receptive field overfits"); the advice is one ResBlock fewer (a field 4 texels narrower),
    else a denoiser trained for :data:`SHORTER_SHARE` of its steps (it memorises less of the layout), or a coarser
    latent. ``narrower_tried``: the fit trained one with a narrower field already (:func:`narrower_field`), which
    did not keep the input's patches: the advice is the shorter training."""
    if (g_div >= VARIED_G_DIV) if g_div is not None else (distance >= COPIES_DISTANCE):
        return None
    d = cfg.diffusion
    shorter = max(1, int(SHORTER_SHARE * d.steps))
    if d.n_resblocks > 1 and not narrower_tried:
        fix = refit_advice(cfg, "diffusion.n_resblocks", d.n_resblocks - 1, also=", which may tear it")
        fix += f"; or a denoiser trained for fewer steps, --set diffusion.steps={shorter}"
    else:
        fix = refit_advice(cfg, "diffusion.steps", shorter)
    coarse = {"detail": "small", "fine": "quick"}.get(cfg.name)
    if coarse:
        fix += f"; or --preset {coarse}, the same field on a coarser latent, which keeps thin walls less well"
    among = "" if g_div is None else f"G-Div {g_div:.3f} among the calibration's samples at diversity 1; "
    less = (
        "one ResBlock fewer, trained here, kept no varied setting that keeps the patches; a denoiser trained for "
        "fewer steps holds less of it"
        if narrower_tried
        else "a narrower field, or a denoiser trained for fewer steps, holds less of it"
    )
    return (
        f"even from pure noise this fit's samples are near copies of the input ({among}their latents differ from "
        f"the input's by {distance:.1%} of its variance): its denoiser's {1 + 4 * d.n_resblocks}-texel field holds "
        f"the layout of this shape, so no diversity setting varies it; {less}: {fix}"
    )


def choose_pbr(mesh: TexturedMesh, pbr: bool | None, preset, say) -> bool:
    """Whether to fit the PBR variant: asked for, or (``pbr=None``) whenever the mesh has PBR maps."""
    already = isinstance(preset, Config) and preset.autoencoder.pbr
    if pbr is None:
        pbr = bool(already or mesh.has_pbr)
        if pbr and mesh.has_pbr:
            say(
                f"[fit] '{mesh.name}' has PBR maps: learning base colour, metallic, roughness and normals (pbr=False: colour only)"
            )
    elif pbr and not mesh.has_pbr:
        say(
            f"[fit] '{mesh.name}' has no PBR maps: learning its constant metallic / roughness and its geometric normals"
        )
    return bool(pbr)


def wall_directions(mesh: TexturedMesh) -> tuple[float, float]:
    """The turn about the up (y) axis, in degrees from −45 to 45, that lines ``mesh``'s walls up with x and z, and how
    well its walls agree on it (0: round, or no walls; 1: every wall along two directions at right angles): the
    mean of ``4 φ`` over its faces' horizontal normals (at angles ``φ``, weighted by their area), in which a wall
    and one at right angles to it count alike."""
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, [0, 2]]  # twice the area, horizontal part
    weight = np.linalg.norm(n, axis=1)
    mean = (weight * np.exp(4j * np.arctan2(n[:, 1], n[:, 0]))).sum() / max(weight.sum(), 1e-300)
    return float(np.degrees(np.angle(mean) / 4)), float(abs(mean))


def choose_turn(mesh: TexturedMesh, turn: float | None, preset, say) -> float:
    """The fit's turn about the up axis (``grid.turn``): ``turn`` where given (or the preset's, where not 0), else
    the one that lines the walls up with x and z where they agree (:func:`wall_directions`): the paper finds that a
    triplane varies a shape along its three axes, and a wall across them is smeared over both planes."""
    if turn is not None or (isinstance(preset, Config) and preset.grid.turn):
        return float(preset.grid.turn if turn is None else turn)
    degrees = wall_turn(mesh)
    if not degrees:
        return 0.0
    say(
        f"[fit] the walls of '{mesh.name}' lie {abs(degrees):.0f}° off the x and z axes: turned along them, for a "
        "triplane varies a shape along its axes; its samples are turned back (--turn 0, Python turn=0: as it lies)"
    )
    return degrees


def up_hint(source) -> str | None:
    """A line for a mesh file whose format says nothing of its up axis (STL, PLY, OFF: often Z-up, as 3D printing and
    CAD make them), fitted without one; None for OBJ and glTF (Y-up) and meshes given in Python."""
    if not isinstance(source, (str, Path)) or Path(source).suffix.lower() not in (".stl", ".ply", ".off"):
        return None
    return (
        f"[fit] {Path(source).suffix[1:].upper()} files do not say which way is up (3D printing and CAD make them "
        "Z-up): if the pictures show it on its side, fit again with --up z (Python up='z')"
    )


def wall_turn(mesh: TexturedMesh) -> float:
    """The turn :func:`choose_turn` makes unasked: the walls' (:func:`wall_directions`) where they agree, else 0."""
    degrees, agree = wall_directions(mesh)
    return round(degrees, 2) if agree >= WALLS_AGREE and abs(degrees) >= LEAST_TURN else 0.0


def as_fitted(mesh: TexturedMesh, up: str | None = None, turn: float | None = None) -> TexturedMesh:
    """``mesh`` in the frame a fit with ``up`` and ``turn`` grids it in (None: the fit's own choice): what the
    estimates made before the fit measure."""
    upright = mesh.turned_upright(up or "y")
    return upright.turned_about_y(wall_turn(upright) if turn is None else turn)
