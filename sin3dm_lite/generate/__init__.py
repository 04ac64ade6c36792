"""Generate: what to sample in the input's coordinates (``control``), SDF → textured mesh (``extract``) and
the mesh writers (``export``)."""
