"""What a fit decides for the user, beyond the paper: one opt-in layer around the plain method.

``fit_default`` (the preset for this machine and this shape, said with the time it should take), ``calibration``
(the diversity knob chosen per shape), ``review`` (the fit's last look: are the samples copies?), ``fit_policy``
(the messages and checks). The CLI uses them; from Python, ``Sin3DM.fit`` without a preset takes the default, and
calibrates the CPU presets unless told ``calibrate=False``.
"""
