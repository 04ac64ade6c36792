"""The application around the method: what runs a fit or a sample run for a user, not what the paper describes.

``fitting`` (the stages of a fit, its checkpoints and Ctrl-C), ``sampling`` (``Sin3DM.sample``'s settings and
decoding), ``run_folder`` / ``checkpoints`` / ``model_file`` (a run folder's files, read and checked),
``runs`` / ``pretrained`` (what a name means: a run folder, a shipped model), ``request`` / ``mass`` /
``mass_folder`` / ``mass_workers`` (many samples into one folder), ``values`` (the checks the CLI and the
Python API share), ``device`` / ``threads`` (CPU or GPU, precision, CPU threads), ``notebook_run``.
"""
