"""What a fit decides for the user, beyond the paper: one opt-in layer around the plain method.

<<<<<<< HEAD
``fit_default`` (the preset for this machine and this shape, said with the time it should take), ``calibration``
(the diversity knob chosen per shape), ``review`` (the fit's last look: are the samples copies?), ``fit_policy``
(the messages and checks). The CLI uses them; from Python, ``Sin3DM.fit`` without a preset takes the default, and
calibrates the CPU presets unless told ``calibrate=False``.
=======
``fit_default`` (the preset for this machine, said with the time it should take), ``fit_policy`` (the
thin-part switch, the wider field's trial, the messages and hints), ``review`` (the fit's last look: the
copies check, the rollout switch), ``calibration`` (the diversity knob chosen per shape). The CLI uses them;
from Python, ``Sin3DM.fit`` applies the preset's switches and the calibration (``sampling.calibrate``).
>>>>>>> h-snap
"""
