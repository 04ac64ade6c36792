"""``open_run`` / ``Sin3DM.open``: RUN names a shipped model, a run folder, or an input fitted once into a cache."""

import shutil

import pytest
from PIL import Image

from sin3dm_lite.app import runs
from sin3dm_lite.app.pretrained import pretrained_path
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.examples import write_example
from sin3dm_lite.pipeline import Sin3DM, open_run

from .conftest import micro_config

pytestmark = pytest.mark.filterwarnings("ignore:low reconstruction quality")


@pytest.fixture
def fit_calls(monkeypatch):
    """Record every ``Sin3DM.fit`` (and still run it); the wall example counts as not shipped."""
    from sin3dm_lite.app import pretrained

    shipped = pretrained.shipped_model
    monkeypatch.setattr(pretrained, "shipped_model", lambda name: None if name.startswith("wall") else shipped(name))
    calls = []
    fit = Sin3DM.fit.__func__

    def spy(cls, source, *a, **k):
        calls.append((source, k.get("resume")))
        return fit(cls, source, *a, **k)

    monkeypatch.setattr(Sin3DM, "fit", classmethod(spy))
    return calls


def test_same_input_and_config_is_fitted_once_then_loaded(tmp_path, fit_calls):
    cfg = micro_config()
    first = open_run("wall", preset=cfg, cache=tmp_path, progress=False)
    assert fit_calls == [("wall", False)] and (first.run_dir / "model.pt").is_file()
    assert first.run_dir.parent == tmp_path and first.run_dir.name.startswith("wall-")
    assert first.run_dir == runs.cached_run("wall", cfg, tmp_path)  # where the next test puts its copy
    again = Sin3DM.open("wall", preset=cfg, cache=tmp_path, progress=False)  # e.g. after a kernel restart
    assert fit_calls == [("wall", False)] and again.run_dir == first.run_dir
    assert again.report == first.report
    # a run folder is loaded as it is
    assert open_run(str(first.run_dir), progress=False).run_dir == first.run_dir
    assert open_run(first.run_dir / "model.pt", progress=False).run_dir == first.run_dir


def test_interrupted_fit_is_resumed(tmp_path, fit_calls, micro_fit):
    cfg = micro_config()
    folder = runs.cached_run("wall", cfg, tmp_path)
    shutil.copytree(micro_fit[1], folder)  # what open_run fits there (this input, these settings): the session's fit
    (folder / "model.pt").unlink()  # as if killed before the end: config and checkpoints are there
    model = open_run("wall", preset=cfg, cache=tmp_path, progress=False)
    assert fit_calls[-1] == ("wall", True) and (folder / "model.pt").is_file() and model.run_dir == folder


def test_the_key_covers_input_and_config(tmp_path):
    cfg = micro_config()
    key = runs.run_key("wall", cfg)
    assert key == runs.run_key("wall", micro_config()) and key.startswith("wall-") and len(key) == len("wall-") + 12
    assert runs.run_key("wall", cfg.updated(**{"diffusion.steps": 31})) != key  # changed config: other folder
    assert runs.run_key("canyon", cfg) != key
    mesh = write_example("wall", tmp_path / "a")
    by_file = runs.run_key(str(mesh), cfg)
    assert by_file.startswith("wall-") and by_file != key  # a file is keyed by what it holds
    copy = tmp_path / "b"
    shutil.copytree(mesh.parent, copy)  # the OBJ with its MTL and texture, elsewhere
    copy = copy / mesh.name
    assert runs.run_key(copy, cfg) == by_file
    copy.write_text(copy.read_text() + "\n# a comment changes nothing the fit reads\n")
    assert runs.run_key(copy, cfg) == by_file
    texture = next(p for p in copy.parent.iterdir() if p.suffix == ".png")
    Image.open(texture).transpose(Image.Transpose.FLIP_LEFT_RIGHT).save(texture)  # another texture: refit
    assert runs.run_key(copy, cfg) != by_file


def test_shipped_names_load_the_shipped_folder(tmp_path, fit_calls):
    model = open_run("canyon", cache=tmp_path, progress=False)
    assert model.run_dir == pretrained_path() and fit_calls == [] and not list(tmp_path.iterdir())
    assert open_run("canyon_small", cache=tmp_path, progress=False).run_dir == pretrained_path()


def test_shipped_examples_default_first():
    from sin3dm_lite.app.pretrained import shipped_examples, shipped_names

    assert shipped_examples()[0] == "canyon" and len(shipped_examples()) == len(shipped_names())


@pytest.mark.parametrize("bad", ["no_such_thing", "missing/model.pt", "", 3])
def test_bad_run_is_one_clear_error(bad, tmp_path):
    with pytest.raises(Sin3DMInputError) as e:
        open_run(bad, cache=tmp_path, progress=False)
    assert "\n" not in str(e.value)
    if bad == "no_such_thing":
        assert "shipped model (canyon" in str(e.value) and "built-in example" in str(e.value)


def test_an_unfinished_run_folder_says_how_to_continue(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text("{}")
    with pytest.raises(Sin3DMInputError, match="--resume"):
        open_run(tmp_path / "run", progress=False)
