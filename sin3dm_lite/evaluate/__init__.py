"""Evaluate: the paper's quality and diversity metrics (``geometry``, ``texture``, ``features``; all of them in
``metrics``), the diversity calibration (``calibrate``) and headless rendering (``render``)."""
