"""Test-wide settings, inherited by the notebook kernels that nbmake starts.

* ``SIN3DM_FAST=1``: notebooks pick the tiny preset (the one switch they read).
* One torch/OpenMP thread: the tiny models are too small to gain from two, and on a
  2-core machine with anything else running, two spinning OpenMP threads made steps
  10-100x slower (measured: 0.02 s vs 2.3 s per tiny diffusion step).
* One export worker per ``sample`` (``SIN3DM_WORKERS=1``): the suite's two processes share
  two cores, where a user's ``sample`` would start one per core (threads.export_workers).
"""

import os

os.environ.setdefault("SIN3DM_FAST", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("SIN3DM_WORKERS", "1")
