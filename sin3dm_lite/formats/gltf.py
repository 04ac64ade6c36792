"""glTF / GLB headers, read before trimesh reads the file: trimesh follows any ``uri`` a file names and drops a
texture it cannot decode without a word, so the files a glTF names are confined here and its broken textures said.
"""

from __future__ import annotations

import base64
import io
import json
import struct
from urllib.parse import unquote

import numpy as np

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


def _bytes(path, header: dict, binary: bytes, item: dict) -> bytes:
    """The bytes of an image or buffer: a data URI, a file beside the glTF, or a buffer view (of the GLB's binary
    chunk where its buffer has no URI). The files were checked by :func:`check_gltf_files`."""
    if "uri" not in item:
        view = header["bufferViews"][item["bufferView"]]
        buf = header["buffers"][view["buffer"]]
        whole = binary if "uri" not in buf else _bytes(path, header, binary, buf)
        return whole[view.get("byteOffset", 0) :][: view["byteLength"]]
    if item["uri"].startswith("data:"):
        return base64.b64decode(item["uri"].split(",", 1)[1])
    if not (path.parent / unquote(item["uri"])).is_file():
        raise FileNotFoundError("file not found")
    return (path.parent / unquote(item["uri"])).read_bytes()


def _texture_source(texture: dict) -> tuple[int | None, list[str]]:
    """The image trimesh reads for a glTF texture (EXT_texture_webp's, else the plain ``source``; a KTX2 image of
    KHR_texture_basisu it cannot decode) and the extensions whose images it leaves unread."""
    ext = texture.get("extensions") if isinstance(texture.get("extensions"), dict) else {}
    webp = ext.get("EXT_texture_webp")
    src = webp.get("source") if isinstance(webp, dict) and webp.get("source") is not None else texture.get("source")
    return src, [k for k, e in ext.items() if k != "EXT_texture_webp" and isinstance(e, dict) and "source" in e]


def gltf_image_problems(path, header: dict, binary: bytes) -> list[str]:
    """A warning for each texture a glTF's materials use that is missing or undecodable (best effort: any other
    surprise gives no warnings). Its external files were checked by :func:`check_gltf_files`."""
    from PIL import Image

    def blob(item):
        return _bytes(path, header, binary, item)

    try:
        images, textures, users, unread = header.get("images", []), header.get("textures", []), {}, {}
        for mat in header.get("materials", []):
            pbr = mat.get("pbrMetallicRoughness", {})
            for slot, info in (
                ("baseColorTexture", pbr.get("baseColorTexture")),
                ("metallicRoughnessTexture", pbr.get("metallicRoughnessTexture")),
                ("normalTexture", mat.get("normalTexture")),
            ):
                if info and info.get("index") is not None and info["index"] < len(textures):
                    tex = textures[info["index"]]
                    user = f"{slot} of material '{mat.get('name', '?')}'"
                    src, other = _texture_source(tex)
                    if src is not None and src < len(images):
                        users.setdefault(src, []).append(user)
                    elif other:
                        unread.setdefault(", ".join(other), []).append(user)
        problems = [
            f"a texture of '{path.name}' ({', '.join(used_by)}) is only in a format this reader cannot decode "
            f"({names}, e.g. KTX2); export the textures as PNG or JPEG; using the material colour instead"
            for names, used_by in unread.items()
        ]
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


#: integer component types: numpy type and, for a ``normalized`` accessor, the value that reads as 1
_INTEGERS = {5120: (np.int8, 127), 5121: (np.uint8, 255), 5122: (np.int16, 32767), 5123: (np.uint16, 65535)}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
#: the texture slots whose KHR_texture_transform moves a material's texture coordinates, the first found wins
_SLOTS = (
    ("pbrMetallicRoughness", "baseColorTexture"),
    ("pbrMetallicRoughness", "metallicRoughnessTexture"),
    (None, "normalTexture"),
)


def plain_gltf(path, header: dict, binary: bytes) -> bytes | None:
    """The glTF rewritten for trimesh, which reads two common extensions wrong without a word (None: nothing to
    rewrite). KHR_mesh_quantization (gltfpack's default) stores positions and texture coordinates as integers, which
    a ``normalized`` accessor maps to [0, 1] or [-1, 1]: trimesh reads the integers (UVs up to 65,535). And the
    KHR_texture_transform of a material's texture (gltfpack's way back to the UVs' own range) is dropped. Here both
    become float coordinates in a buffer of their own, the transform applied; a material textured through another
    coordinate set than the first gets it as TEXCOORD_0 (the one trimesh reads); the rest of the file is unchanged."""
    used = header.get("extensionsUsed")
    other_set = any(_uv_transform(m)[0] for m in header.get("materials", []) if isinstance(m, dict))
    if not other_set and (
        not isinstance(used, list) or not {"KHR_mesh_quantization", "KHR_texture_transform"} & set(used)
    ):
        return None
    header = json.loads(json.dumps(header))
    for key in ("buffers", "bufferViews", "accessors"):
        header.setdefault(key, [])
    made, cache = [], {}
    for prim in (p for mesh in header.get("meshes", []) for p in mesh.get("primitives", [])):
        material = header.get("materials", [])[prim["material"]] if "material" in prim else {}
        coord, matrix = _uv_transform(material)
        for name, index in list(prim.get("attributes", {}).items()):
            acc = header["accessors"][index]
            moved = matrix if name == f"TEXCOORD_{coord}" else None
            quantized = acc.get("normalized") and acc.get("componentType") in _INTEGERS
            if moved is None and not (quantized and (name == "POSITION" or name.startswith("TEXCOORD_"))):
                continue
            key = (index, None if moved is None else moved.tobytes())
            if key not in cache:
                values = _accessor_values(path, header, binary, acc)
                cache[key] = _add_accessor(
                    header, made, values if moved is None else values @ moved[:2, :2].T + moved[:2, 2]
                )
            prim["attributes"][name] = cache[key]
        if coord and f"TEXCOORD_{coord}" in prim.get("attributes", {}):  # trimesh reads TEXCOORD_0 only
            prim["attributes"]["TEXCOORD_0"] = prim["attributes"][f"TEXCOORD_{coord}"]
    for material in header.get("materials", []):
        for parent, slot in _SLOTS:
            info = (material.get(parent, {}) if parent else material).get(slot)
            if isinstance(info, dict):
                info.get("extensions", {}).pop("KHR_texture_transform", None)
    blob = b"".join(made)
    if not blob and not other_set:
        return None
    if blob:
        uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        header["buffers"].append({"byteLength": len(blob), "uri": uri})
    for key in ("extensionsUsed", "extensionsRequired"):
        if isinstance(header.get(key), list):
            header[key] = [e for e in header[key] if e not in ("KHR_mesh_quantization", "KHR_texture_transform")]
    text = json.dumps(header).encode()
    if path.suffix.lower() == ".gltf":
        return text
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I", len(text)) + b"JSON" + text
    if binary:
        padded = binary + b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<I", len(padded)) + b"BIN\0" + padded
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _uv_transform(material: dict) -> tuple[int, np.ndarray | None]:
    """A material's texture coordinate set and its KHR_texture_transform as a 3×3 matrix (glTF's: offset · rotation
    · scale), or None."""
    for parent, slot in _SLOTS:
        info = (material.get(parent, {}) if parent else material).get(slot)
        if not isinstance(info, dict):
            continue
        ext = (info.get("extensions") or {}).get("KHR_texture_transform")
        if not isinstance(ext, dict):
            return int(info.get("texCoord", 0)), None
        (ox, oy), r, (sx, sy) = ext.get("offset", (0, 0)), float(ext.get("rotation", 0)), ext.get("scale", (1, 1))
        c, s = np.cos(r), np.sin(r)
        matrix = np.array([[c * sx, s * sy, ox], [-s * sx, c * sy, oy], [0, 0, 1]], np.float64)
        return int(ext.get("texCoord", info.get("texCoord", 0))), matrix
    return 0, None


def _accessor_values(path, header: dict, binary: bytes, acc: dict) -> np.ndarray:
    """An accessor's values ``(count, width)`` in float64, a ``normalized`` integer one mapped as glTF says."""
    kind = acc["componentType"]
    dtype = np.dtype(_INTEGERS[kind][0] if kind in _INTEGERS else {5125: np.uint32, 5126: np.float32}[kind])
    count, width = int(acc["count"]), _WIDTH[acc["type"]]
    view = header["bufferViews"][acc["bufferView"]]
    data = _bytes(path, header, binary, {"bufferView": acc["bufferView"]})[acc.get("byteOffset", 0) :]
    item = dtype.itemsize * width
    stride = view.get("byteStride") or item
    if count < 1 or stride < item or stride * (count - 1) + item > len(data):
        raise ValueError("an accessor reaches beyond its buffer")  # a crafted count never allocates
    rows = np.frombuffer(data[: stride * (count - 1) + item].ljust(stride * count, b"\0"), np.uint8).reshape(
        count, stride
    )
    values = rows[:, :item].copy().view(dtype).reshape(count, width).astype(np.float64)
    if acc.get("normalized") and kind in _INTEGERS:
        values = np.maximum(values / _INTEGERS[kind][1], -1.0)
    return values


def _add_accessor(header: dict, made: list, values: np.ndarray) -> int:
    """A float32 accessor of ``values`` in the buffer this rewrite appends (``made``: its pieces); its index."""
    data = np.ascontiguousarray(values, np.float32).tobytes()
    offset = sum(len(b) for b in made)
    made.append(data)
    header["bufferViews"].append({"buffer": len(header["buffers"]), "byteOffset": offset, "byteLength": len(data)})
    header["accessors"].append(
        {
            "bufferView": len(header["bufferViews"]) - 1,
            "componentType": 5126,
            "count": len(values),
            "type": {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}[values.shape[1]],
            "min": values.min(0).tolist(),
            "max": values.max(0).tolist(),
        }
    )
    return len(header["accessors"]) - 1
