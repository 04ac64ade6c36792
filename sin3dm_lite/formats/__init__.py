"""Mesh file formats: the readers behind :func:`~.load.load_mesh` (``obj`` + ``mtl`` parsed here, ``scene`` through
trimesh, ``gltf`` headers, shared parts in ``common``), the writers in ``export`` and the image helpers in ``images``.
"""
