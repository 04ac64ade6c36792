"""What a fit decides for the user, beyond the paper: ``fit_default`` (the preset for this machine and shape, and
its time), ``calibration`` (the diversity knob per shape), ``review`` (are the samples copies?) and ``fit_policy``
(the messages and checks). ``Sin3DM.fit`` without a preset takes the default and calibrates the CPU presets.
"""
