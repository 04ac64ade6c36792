"""The thread policy: one thread, idle threads sleep (so processes sharing the CPU don't stall), the user's choice wins."""

import os
import subprocess
import sys

from sin3dm_lite.app.threads import SPIN_COUNT, apply_policy, chosen_threads, threads_hint

PROBE = "import os, sin3dm_lite, torch; print(os.environ.get('OMP_WAIT_POLICY'), torch.get_num_threads())"
OURS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "KMP_BLOCKTIME", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "SIN3DM_THREADS")


def _probe(code=PROBE, **env):
    clean = {k: v for k, v in os.environ.items() if k not in OURS}
    out = subprocess.run([sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True, check=True)
    policy, threads = out.stdout.split()
    return policy, int(threads)


def test_import_gives_one_thread_that_sleeps_when_idle():
    assert _probe() == ("PASSIVE", 1)


def test_the_users_settings_win():
    assert _probe(OMP_WAIT_POLICY="ACTIVE")[0] == "ACTIVE"
    assert _probe(GOMP_SPINCOUNT="300000")[0] == "None"
    assert _probe(OMP_NUM_THREADS="2")[1] == 2
    spin = "import os, sin3dm_lite, torch; print(os.environ.get('GOMP_SPINCOUNT'), torch.get_num_threads())"
    assert _probe(spin, SIN3DM_THREADS="2") == (SPIN_COUNT, 2)  # asked-for threads spin briefly
    # torch loaded first and set by the user: kept; loaded first at its default: one thread
    assert (
        _probe(
            "import torch; torch.set_num_threads(3); import os, sin3dm_lite; "
            "print(os.environ.get('OMP_WAIT_POLICY'), torch.get_num_threads())"
        )[1]
        == 3
    )
    assert (
        _probe("import torch, os, sin3dm_lite; print(os.environ.get('OMP_WAIT_POLICY'), torch.get_num_threads())")[1]
        == 1
    )


def test_apply_policy_on_a_given_environment(monkeypatch):
    from sin3dm_lite.app import threads

    monkeypatch.setattr(threads, "usable_cores", lambda: 4)  # SIN3DM_THREADS is capped at the cores
    env = {}
    assert apply_policy(env) == {"OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"} and env == apply_policy({})
    env = {"KMP_BLOCKTIME": "0", "MKL_NUM_THREADS": "4"}
    assert apply_policy(env) == {} and "OMP_WAIT_POLICY" not in env and "OMP_NUM_THREADS" not in env
    assert chosen_threads({"SIN3DM_THREADS": "3"}) == 3 and chosen_threads({"SIN3DM_THREADS": "x"}) == 1


def test_more_threads_asked_for_spin_briefly_instead_of_sleeping():
    # two threads that sleep at once ran a quick training step slower than one: asked-for threads spin a little
    env = {"SIN3DM_THREADS": "2"}
    assert apply_policy(env) == {"GOMP_SPINCOUNT": SPIN_COUNT, "OMP_NUM_THREADS": "2"}
    assert "OMP_WAIT_POLICY" not in env
    # the user's wait policy or thread count still wins
    env = {"SIN3DM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE"}
    assert apply_policy(env) == {"OMP_NUM_THREADS": "2"}
    assert apply_policy({"SIN3DM_THREADS": "2", "OMP_NUM_THREADS": "1"}) == {"OMP_WAIT_POLICY": "PASSIVE"}


def test_the_threads_hint_only_where_the_policy_chose_one_thread_of_several_cores():
    hint = threads_hint({"OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"}, cores=2)
    assert "SIN3DM_THREADS=2" in hint and "2-core" in hint and "slower beside another" in hint
    assert threads_hint({"OMP_NUM_THREADS": "1"}, cores=1) is None  # one core: nothing to gain
    assert threads_hint({}, cores=4) is None  # the user's OMP_NUM_THREADS won
    assert threads_hint({"GOMP_SPINCOUNT": SPIN_COUNT, "OMP_NUM_THREADS": "2"}, cores=2) is None  # asked for 2


def test_export_workers_one_per_core_shared_among_ranks_at_most_four(monkeypatch):
    """`sample` without --workers exports in one process per usable core, split among the torchrun ranks of this
    machine, 1 to 4; an explicit --workers (0 too) is kept."""
    from sin3dm_lite.app import threads
    from sin3dm_lite.app.request import SampleRequest

    for cores, local, want in [(1, "1", 1), (2, "1", 2), (2, "2", 1), (16, "1", 4), (16, "8", 2), (8, "x", 4)]:
        monkeypatch.setattr(threads, "usable_cores", lambda c=cores: c)
        assert threads.export_workers({"LOCAL_WORLD_SIZE": local}) == want, (cores, local)
    assert threads.export_workers({"SIN3DM_WORKERS": "3", "LOCAL_WORLD_SIZE": "2"}) == 3  # the user's number wins
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    monkeypatch.delenv("SIN3DM_WORKERS", raising=False)  # the suite's own setting (conftest)
    assert SampleRequest().export_workers() == 2
    assert SampleRequest(workers=0).export_workers() == 0 and SampleRequest(workers=3).export_workers() == 3
    assert threads.usable_cores() >= 1


def test_the_default_workers_drop_to_what_memory_holds(monkeypatch):
    """Without --workers, sample lowers its one-per-core default where the exports would not fit in memory,
    instead of refusing; an explicit --workers that does not fit is refused (tests/test_bad_inputs.py)."""
    from sin3dm_lite.app import device, mass, threads
    from sin3dm_lite.app.request import SampleRequest
    from sin3dm_lite.app.sampling import EXPORT_BYTES_PER_TEXEL, EXPORT_BYTES_PER_VOXEL
    from sin3dm_lite.pipeline import Sin3DM

    monkeypatch.delenv("SIN3DM_WORKERS", raising=False)
    monkeypatch.setattr(threads, "usable_cores", lambda: 4)
    model = Sin3DM.open("canyon")
    plan = model.plan()
    one_export = 4096**2 * EXPORT_BYTES_PER_TEXEL + 128**3 * EXPORT_BYTES_PER_VOXEL  # at most, any box
    monkeypatch.setattr(device, "memory_available", lambda kind="cpu": 4.4 * one_export)  # half of it: 2.2 exports
    req = SampleRequest(texture_size=4096, mesh_resolution=128)
    mass.check_sample_sizes(model, plan, req)
    assert req.workers == 2
    monkeypatch.setattr(device, "memory_available", lambda kind="cpu": 1e15)
    req = SampleRequest()
    mass.check_sample_sizes(model, plan, req)
    assert req.workers == 4
