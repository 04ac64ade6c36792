"""sin3dm-lite: a readable reimplementation of Sin3DM (ICLR 2024) for learning and for use.

From one textured mesh: a truncated SDF + colour grid (``grid``), a triplane
latent (``autoencoder``), a small-receptive-field diffusion model on the
triplane (``unet``, ``diffusion``), and new textured meshes (``extract``,
``export``). ``pipeline.Sin3DM`` ties the stages together.
"""

__version__ = "0.1.0"
