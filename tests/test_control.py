"""Controlled generation: what is kept stays the input's, what is freed varies, sizes and errors are right."""

import copy

import numpy as np
import pytest
import torch

from sin3dm_lite import cli
from sin3dm_lite.app.pretrained import shipped_model
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.generate import control

REGENERATE = ((0.25, 0.0, 0.0), (0.6, 1.0, 1.0))  # a slab across x: reaches the faces along y and z
DUPLICATE = (((0.0, 0.0, 0.0), (0.3, 1.0, 1.0)), (0.6, 0.0, 0.0))


@pytest.fixture(scope="module")
def model(micro_fit):
    from .conftest import micro_model

    return micro_model(micro_fit)


def _kept_mask(plan):
    return [(m[0, 0] >= 1.0) for m in plan.mask.planes]


def _free_mask(plan):
    return [(m[0, 0] <= 0.0) for m in plan.mask.planes]


@pytest.mark.parametrize(
    "kw", [{"regenerate": REGENERATE}, {"duplicate": DUPLICATE}, {"outpaint": (1.5, 1.0, 1.0), "anchor": "x-"}]
)
def test_kept_part_is_the_known_latent_at_every_step_and_exactly_at_the_end(model, kw):
    """Two denoisers, same seed: the kept texels are the same noised known latent after every step, the rest is not."""
    other = copy.deepcopy(model)
    with torch.no_grad():
        for p in other.denoiser.parameters():
            p.add_(0.05 * torch.randn_like(p))
    a = model.sample(2, seed=1, return_intermediates=list(range(50)), progress=False, **kw)
    b = other.sample(2, seed=1, return_intermediates=list(range(50)), progress=False, **kw)
    kept, free = _kept_mask(a.plan), _free_mask(a.plan)
    assert all(k.any() for k in kept) or a.plan.kind == "regenerate"
    assert len(a.intermediates) > 5
    for ea, eb in zip(a.intermediates[1:], b.intermediates[1:]):  # x_t of step i = the end of step i - 1
        for pa, pb, k in zip(ea["x_t"].planes, eb["x_t"].planes, kept):
            assert torch.equal(pa[:, :, k], pb[:, :, k])
    assert any(
        not torch.equal(pa[:, :, f], pb[:, :, f])
        for pa, pb, f in zip(a.triplane.planes, b.triplane.planes, free)
        if f.any()
    )
    for pa, kn, k in zip(a.triplane.planes, a.plan.known.planes, kept):  # the end: the known latent itself
        assert torch.equal(pa[:, :, k], kn.expand_as(pa)[:, :, k])


def test_decoded_kept_region_matches_the_reconstruction(model):
    s = model.sample(2, seed=0, regenerate=REGENERATE, progress=False)
    res = 24
    occ, rec = model.occupancy(s, res), model.occupancy(model.input_sample(), res)[0]
    kept = s.plan.kept(occ[0].shape)
    assert kept.mean() > 0.3
    for o in occ:
        inter, union = (o & rec)[kept].sum(), (o | rec)[kept].sum()
        assert inter / union >= 0.9


def test_regenerated_part_differs_between_seeds_and_the_rest_does_not(model):
    a = model.sample(1, seed=0, regenerate=REGENERATE, progress=False)
    b = model.sample(1, seed=1, regenerate=REGENERATE, progress=False)
    free, kept = _free_mask(a.plan), _kept_mask(a.plan)
    diffs = [
        float((pa - pb)[:, :, f].abs().mean())
        for pa, pb, f in zip(a.triplane.planes, b.triplane.planes, free)
        if f.any()
    ]
    assert diffs and max(diffs) > 1e-3  # (the micro model has trained 30 steps: its samples vary little)
    assert all(torch.equal(pa[:, :, k], pb[:, :, k]) for pa, pb, k in zip(a.triplane.planes, b.triplane.planes, kept))


@pytest.mark.parametrize("trim", [0, 2])
def test_duplicate_copies_the_box(model, trim):
    plan = control.duplicate(model.latent, model.aabb, *DUPLICATE, trim=trim)
    n = model.latent.resolution[0]
    a0, a1 = control.texel_range(0.0, 0.3, n)
    d0 = control.texel_range(0.6, 0.9, n)[0]
    a0, d0 = a0 + trim, d0 + trim  # the box touches the x- face, the copy does not: its margin stays behind
    xy = plan.known.xy[0]
    assert torch.equal(xy[:, d0 : d0 + a1 - a0], model.latent.xy[0][:, a0:a1])
    assert torch.equal(xy[:, :d0], model.latent.xy[0][:, :d0])  # nothing else changes
    assert plan.kept()[d0 : d0 + a1 - a0].any() and plan.kept()[a0:a1].any()
    assert not plan.kept()[:trim].any()


@pytest.mark.parametrize("anchor", control.ANCHORS)
def test_outpainted_and_retargeted_boxes_have_the_requested_size(model, anchor):
    texel = (model.aabb[3:] - model.aabb[:3]) / np.array(model.latent.resolution)
    factors = np.array([1.5, 1.0, 1.25])
    for plan in (model.plan(outpaint=factors, anchor=anchor), model.plan(resize=factors)):
        size = plan.aabb[3:] - plan.aabb[:3]
        assert np.all(np.abs(size - factors * (model.aabb[3:] - model.aabb[:3])) <= texel / 2 + 1e-6), plan.kind
        assert plan.resolution == tuple(int(r) for r in np.round(np.array(model.latent.resolution) * factors))
    plan = model.plan(outpaint=factors, anchor=anchor)
    lo, hi = plan.aabb[:3], plan.aabb[3:]  # the input keeps its place inside the new box
    assert np.all(lo <= model.aabb[:3] + 1e-6) and np.all(hi >= model.aabb[3:] - 1e-6)
    if anchor != "center":
        axis = "xyz".index(anchor[0])
        face = (lo if anchor[1] == "-" else hi)[axis]
        assert face == pytest.approx((model.aabb[:3] if anchor[1] == "-" else model.aabb[3:])[axis])


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"regenerate": ((0.3, 0.3, 0.3), (0.6, 0.6, 0.6))}, "faces along at least one axis"),
        ({"regenerate": ((0.5, 0, 0), (0.5, 1, 1))}, "empty along x"),
        ({"regenerate": ((0, 0, 0), (1.2, 1, 1))}, "fractions of the model's box"),
        ({"regenerate": ((0, 0), (1, 1))}, "two corners"),
        ({"duplicate": (((0, 0, 0), (0.5, 1, 1)), (0.8, 0, 0))}, "does not fit"),
        ({"duplicate": (((0, 0, 0), (0.5, 1, 1)), (0.2, 0, 0))}, "overlaps"),
        ({"duplicate": ((0, 0, 0), (0.5, 1, 1))}, "two corners"),
        ({"duplicate": (((0, 0, 0), (0.3, 1, 1)), (0.5, -1, 0))}, "copy to must be"),
        ({"outpaint": (0.5, 1, 1)}, "outpaint factors must be from 1 to 8"),
        ({"outpaint": (2, 1, 1), "anchor": "left"}, "unknown anchor"),
        ({"outpaint": (2, 1, 1), "resize": (2, 1, 1)}, "one control at a time"),
        ({"resize": (0, 1, 1)}, r"resize factors must be in \(0, 8\]"),
    ],
)
def test_bad_requests_give_one_clear_error(model, kw, words):
    with pytest.raises(Sin3DMInputError, match=words):
        model.sample(1, progress=False, **kw)


def test_cli_controls_write_meshes_and_refuse_bad_boxes(model, tmp_path, capsys):
    run = tmp_path / "run"
    model.save(run)
    out = tmp_path / "out"
    assert (
        cli.main(["sample", str(run), "-n", "1", "--outpaint", "1.5", "1", "1", "--anchor", "x+", "--out", str(out)])
        == 0
    )
    assert (out / "000" / "mesh.obj").is_file() and (out / "index.html").is_file()
    capsys.readouterr()
    bad = tmp_path / "bad"
    assert (
        cli.main(
            ["sample", str(run), "-n", "1", "--regenerate", "0.3", "0.3", "0.3", "0.6", "0.6", "0.6", "--out", str(bad)]
        )
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "faces along at least one axis" in err[0] and not bad.exists()


def test_a_shipped_model_is_found_by_name():
    assert shipped_model("canyon") == shipped_model("canyon_small") is not None
    assert (shipped_model("canyon") / "model.pt").is_file()
    assert shipped_model("no_such_model") is None and shipped_model("../canyon_small") is None


def test_control_panel_redraws_the_mask_explains_refusals_and_samples(model):
    from sin3dm_lite import widgets

    panel = widgets.control_panel(model, n_samples=1, resolution=16, steps=5)
    assert panel.last_error is None and len(panel.last_figure.axes) == 3  # the request on three planes
    panel.controls["z"].value = (0.2, 0.8)
    panel.controls["y"].value = (0.2, 0.8)  # reaches no pair of faces: refused, with the reason shown
    assert "not possible" in panel.last_figure.texts[0].get_text()
    panel.controls["z"].value = (0.0, 1.0)
    figs = panel.run()
    assert len(panel.last_samples) == 1 and panel.last_samples.plan.kind == "regenerate"
    assert len(figs[0].axes) == 6 and len(figs[1].axes) == 4  # request + sample; input + sample, two views each


def test_keep_planes_keeps_whole_planes_exactly_and_samples_the_others(model):
    import sin3dm_lite

    assert sin3dm_lite.control.keep_planes is control.keep_planes  # the public namespace notebook 06 uses
    for keep in (["xz"], ["xy", "yz"]):
        plan = control.keep_planes(model.latent, model.aabb, keep)
        assert plan.kind == "keep planes" and plan.request == {"planes": keep}
        s = model.sample(2, plan=plan, seed=0, progress=False)
        assert s.triplane.resolution == model.latent.resolution and not plan.kept().any()  # no voxel keeps all three
        for name, got, given in zip(("xy", "xz", "yz"), s.triplane.planes, model.latent.planes):
            if name in keep:
                assert torch.equal(got, given.expand_as(got))
            else:  # generated: neither the input's nor the same for two seeds
                assert not torch.allclose(got[0], given[0]) and not torch.allclose(got[0], got[1])
    for bad in ("ab", [], ["xz", "zx"]):
        with pytest.raises(Sin3DMInputError, match="xy, xz, yz"):
            control.keep_planes(model.latent, model.aabb, bad)
