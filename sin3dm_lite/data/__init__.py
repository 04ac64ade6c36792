"""Data: settings and presets (``config``), box and grid geometry (``box``), meshes and their file formats
(``mesh_io``), the built-in example shapes (``examples``) and mesh → truncated SDF + colour grid (``grid``)."""
