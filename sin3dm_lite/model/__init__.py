"""Model: the triplane latent (``triplane``), what both trainers share (``training``), the autoencoder
(``autoencoder``), decoder queries and SDF grids (``decode``), the triplane U-Net (``unet``) and the
diffusion schedule, loss and samplers (``diffusion``)."""
