"""glTF / GLB headers, read before trimesh reads the file: trimesh follows any ``uri`` a file names and drops a
texture it cannot decode without a word, so the files a glTF names are confined here and its broken textures said.
"""

from __future__ import annotations

import base64
import io
import json
import struct
from urllib.parse import unquote

from ..errors import Sin3DMInputError
from .common import Scope, resolve_asset, unreadable


def check_compression(path, header: dict) -> None:
    """Refuse a glTF whose geometry is compressed in a way trimesh cannot decode here: Draco without the DracoPy
    package (trimesh's decoder for it) or meshoptimizer (which it never decodes: the bytes would read as garbage)."""
    required = header.get("extensionsRequired")
    required = set(required) if isinstance(required, list) and all(isinstance(e, str) for e in required) else set()
    if "KHR_draco_mesh_compression" in required:
        try:
            import DracoPy  # noqa: F401
        except ImportError:
            raise Sin3DMInputError(
                f"'{path.name}' is compressed with Draco (KHR_draco_mesh_compression), which needs the DracoPy "
                "package: install it (pip install DracoPy), or export the mesh again uncompressed (Blender: File > "
                "Import > glTF 2.0, then File > Export > glTF 2.0 with Compression off)"
            ) from None
    meshopt = sorted(required & {"EXT_meshopt_compression", "KHR_meshopt_compression"})
    if meshopt:
        raise Sin3DMInputError(
            f"'{path.name}' is compressed with meshoptimizer ({meshopt[0]}), which this reader cannot decode; export "
            "the mesh again without compression from the program that made it (gltfpack: without -c)"
        )


def check_gltf_files(path, header: dict, scope: Scope) -> None:
    """Refuse a glTF whose buffers or images are files outside the mesh's folder (unless ``scope`` allows)."""
    for kind in ("buffers", "images"):
        for item in header.get(kind, []) if isinstance(header.get(kind), list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                resolve_asset(unquote(uri), path.parent, scope, f"the glTF {kind[:-1]}", cwd=False)


def gltf_json(path, fmt: str) -> tuple[dict, bytes]:
    """A glTF's JSON and (GLB) binary chunk; a clear error if it is not glTF at all, ``({}, b"")`` on other surprises."""
    data = path.read_bytes()
    if path.suffix.lower() == ".gltf":
        try:
            header = json.loads(data.decode("utf-8"))
        except ValueError as exc:  # UnicodeDecodeError is one
            raise unreadable(path, fmt, f"not valid JSON: {exc}") from None
        return (header if isinstance(header, dict) else {}), b""
    if data[:4] != b"glTF":
        raise unreadable(path, fmt, "it does not start with the GLB magic bytes 'glTF'")
    try:  # 12-byte header, then the JSON chunk and the binary chunk
        off = 20 + struct.unpack_from("<I", data, 12)[0]
        header = json.loads(data[20:off])
        binary = data[off + 8 : off + 8 + struct.unpack_from("<I", data, off)[0]] if off + 8 <= len(data) else b""
        return (header if isinstance(header, dict) else {}), binary
    except Exception:
        return {}, b""


def gltf_image_problems(path, header: dict, binary: bytes) -> list[str]:
    """A warning for each texture a glTF's materials use that is missing or undecodable (best effort: any other
    surprise gives no warnings). Its external files were checked by :func:`check_gltf_files`."""
    from PIL import Image

    def blob(item):  # the bytes of an image or buffer: data URI, file beside the glTF, or buffer view
        if "uri" not in item:
            view = header["bufferViews"][item["bufferView"]]
            buf = header["buffers"][view["buffer"]]
            return (binary if "uri" not in buf else blob(buf))[view.get("byteOffset", 0) :][: view["byteLength"]]
        if item["uri"].startswith("data:"):
            return base64.b64decode(item["uri"].split(",", 1)[1])
        if not (path.parent / unquote(item["uri"])).is_file():
            raise FileNotFoundError("file not found")
        return (path.parent / unquote(item["uri"])).read_bytes()

    try:
        images, textures, users = header.get("images", []), header.get("textures", []), {}
        for mat in header.get("materials", []):
            pbr = mat.get("pbrMetallicRoughness", {})
            for slot, info in (
                ("baseColorTexture", pbr.get("baseColorTexture")),
                ("metallicRoughnessTexture", pbr.get("metallicRoughnessTexture")),
                ("normalTexture", mat.get("normalTexture")),
            ):
                if info and info.get("index") is not None and info["index"] < len(textures):
                    tex = textures[info["index"]]
                    exts = [e for e in (tex.get("extensions") or {}).values() if isinstance(e, dict) and "source" in e]
                    src = exts[-1]["source"] if exts else tex.get("source")
                    if src is not None and src < len(images):
                        users.setdefault(src, []).append(f"{slot} of material '{mat.get('name', '?')}'")
        problems = []
        for src, used_by in users.items():
            im = images[src]
            label = (
                f"'{unquote(im['uri'])}'" if "uri" in im and not im["uri"].startswith("data:") else f"#{src} (embedded)"
            )
            try:
                with Image.open(io.BytesIO(blob(im))) as pil:
                    pil.verify()
            except Exception as exc:
                reason = (
                    "not a readable image" if "cannot identify image" in str(exc) else f"{type(exc).__name__}: {exc}"
                )
                problems.append(
                    f"texture image {label} in '{path.name}' ({', '.join(used_by)}) is missing or "
                    f"unreadable ({reason}); using the material colour instead"
                )
        return problems
    except Exception:
        return []
