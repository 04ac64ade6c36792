"""Test-wide settings: notebooks run with the tiny preset (the one switch they read)."""
import os

os.environ.setdefault("SIN3DM_FAST", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
