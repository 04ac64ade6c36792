"""Generate: what to sample in the input's coordinates (``control``) and SDF → textured mesh (``extract``, with
its texture baking in ``bake``); the mesh writers are ``formats.export``."""
