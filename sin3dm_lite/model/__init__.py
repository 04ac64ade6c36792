"""Model: the triplane latent (``triplane``), what both trainers share (``training``), the autoencoder
(``autoencoder``), decoder queries and SDF grids (``decode``), the triplane U-Net (``unet``), the noise schedule
and the steps a sampler visits (``schedule``) and the diffusion loss, trainer and samplers (``diffusion``)."""
