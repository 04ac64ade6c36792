"""Evaluate: the paper's quality and diversity metrics (``geometry``, ``texture``, ``features``; all of them in
``metrics``), the diversity calibration (``calibrate``, its record in ``calibration_record``) and headless rendering
(``render``)."""
