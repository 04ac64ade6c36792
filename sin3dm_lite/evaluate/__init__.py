"""Evaluate: the paper's quality and diversity metrics (``geometry``, ``texture``, ``features``, ``ssfid``; all
but SSFID in ``metrics``), the diversity calibration (``calibrate``, its record in ``calibration_record``) and headless rendering
(``render``)."""
