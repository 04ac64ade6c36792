"""Mesh file formats: the readers behind :func:`sin3dm_lite.formats.load.load_mesh`, and image helpers.

* ``common`` – what every reader shares: the mesh's folder (:class:`~.common.Scope`), errors and warnings,
  joining the parts into one :class:`~sin3dm_lite.data.mesh.TexturedMesh` (:func:`~.common.assemble`);
* ``obj`` + ``mtl`` – Wavefront OBJ and its material libraries, parsed here;
* ``scene`` – glTF / GLB, PLY, STL, OFF through trimesh; ``gltf`` reads a glTF's header first (files it
  names, textures it uses);
* ``images`` – texture files and arrays as float RGB, and back to 8-bit images and PNG bytes.

The writers are in :mod:`sin3dm_lite.formats.export`.
"""
