"""Evaluate: quality and diversity metrics (``metrics``), the diversity calibration (``calibrate``) and
headless rendering (``render``)."""
