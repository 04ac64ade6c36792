"""The thread policy: idle OpenMP threads sleep (so processes sharing the CPU don't stall), the user's settings win."""
import os
import subprocess
import sys

from sin3dm_lite.threads import apply_wait_policy

PROBE = "import os, sin3dm_lite, torch; print(os.environ.get('OMP_WAIT_POLICY'), torch.get_num_threads())"


def _probe(**env):
    clean = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "KMP_BLOCKTIME",
                                                                 "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env}, capture_output=True, text=True, check=True)
    policy, threads = out.stdout.split()
    return policy, int(threads)


def test_import_makes_idle_threads_sleep_and_keeps_the_thread_count():
    policy, threads = _probe()
    assert policy == "PASSIVE"
    assert threads == _probe(OMP_WAIT_POLICY="ACTIVE")[1]  # the number of threads is PyTorch's own


def test_the_users_settings_win():
    assert _probe(OMP_WAIT_POLICY="ACTIVE")[0] == "ACTIVE"
    assert _probe(GOMP_SPINCOUNT="300000")[0] == "None"
    assert _probe(OMP_NUM_THREADS="1")[1] == 1


def test_apply_wait_policy_on_a_given_environment():
    env = {}
    assert apply_wait_policy(env) == "PASSIVE" and env == {"OMP_WAIT_POLICY": "PASSIVE"}
    env = {"KMP_BLOCKTIME": "0"}
    assert apply_wait_policy(env) is None and "OMP_WAIT_POLICY" not in env
