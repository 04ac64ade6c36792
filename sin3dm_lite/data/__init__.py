"""Data: settings (``config``) and the named presets (``presets``), box and grid geometry (``box``), the mesh type
(``mesh``), reading meshes (``load``, with the file formats in ``formats``) and writing them (``export``), the
built-in example shapes (``examples``), distances to a mesh (``distance``) and mesh → truncated SDF + colour grid
(``grid``, computed by ``tsdf``)."""
