"""MTL material libraries: the ``newmtl`` blocks an OBJ uses (``Kd``, ``d``/``Tr``, ``map_Kd`` with ``-s``/``-o``,
the PBR extensions ``Pm``/``Pr``/``map_Pm``/``map_Pr`` and the normal map ``map_Bump``/``bump``/``norm``), with their
textures found beside the MTL file, decoded once each; a missing or unreadable one is a warning.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from ..data.mesh import DEFAULT_COLOR, Material
from .common import Scope, resolve_asset, warn
from .images import array_to_pil, image_to_array, named_image_warnings


def read_libraries(entries: list[str], path: Path, used: set, scope: Scope, max_size):
    """The materials named in ``used`` from the ``mtllib`` lines ``entries`` of the OBJ ``path``.

    Returns ``({name: (material, uv transform or None)}, whether any library was read)``; a library that is
    missing or unreadable is a warning.
    """
    texture = partial(load_texture, max_size=max_size, cache={}, scope=scope)
    library: dict[str, tuple[Material, tuple | None]] = {}
    loaded_any = False
    for entry in (e.strip() for e in entries):
        # "mtllib a.mtl b.mtl", unless that is one file name with spaces
        for name in (
            entry.split()
            if " " in entry and not resolve_asset(entry, path.parent, scope, "the material library")
            else [entry]
        ):
            mtl = resolve_asset(name, path.parent, scope, "the material library")
            if mtl is None:
                warn(
                    f"material library '{name}' named in '{path.name}' was not found (looked in '{path.parent}'); "
                    "using plain colours: put the .mtl file next to the .obj"
                )
                continue
            try:
                library.update(parse_mtl(mtl, used, texture))
                loaded_any = True
            except OSError as exc:
                warn(f"material library '{mtl.name}' could not be read ({exc}); using plain colours")
    return library, loaded_any


def parse_mtl(path, used: set, texture) -> dict[str, tuple[Material, tuple | None]]:
    """The ``newmtl`` blocks of an MTL file → ``{name: (material, uv transform or None)}``, in file order.

    Only the materials named in ``used`` are built, so textures that no face shows are neither decoded nor warned
    about; ``texture`` loads an image (:func:`load_texture`). A loaded map replaces its scalar (``map_Kd`` → ``Kd``,
    as Blender and three.js read them). The uv transform is ``(scale, offset)`` from ``map_Kd -s/-o``.
    """
    raw: dict[str, dict] = {}
    cur: dict = {}  # statements before the first newmtl belong to no material
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        key, rest = (line.split(None, 1) + ["", ""])[:2]
        k, rest = key.lower(), rest.strip()
        try:
            if key == "newmtl":
                cur = raw.setdefault(rest, {})
            elif k == "kd":
                vals = [float(x) for x in rest.split()[:3]]
                cur["Kd"] = vals * 3 if len(vals) == 1 else vals
            elif k == "d":
                cur["d"] = float(rest.split()[-1])
            elif k == "tr" and "d" not in cur:
                cur["d"] = 1.0 - float(rest.split()[-1])
            elif k in ("pm", "pr"):
                cur[k] = float(rest.split()[0])
            elif k in ("map_kd", "map_pm", "map_pr", "map_bump", "bump", "norm"):
                cur[k] = parse_tex_line(rest)
        except (ValueError, IndexError):
            continue  # a malformed optional line: ignore it like other viewers do
    out = {}
    for mname, d in raw.items():
        if mname not in used:
            continue
        kd = np.clip((d.get("Kd", list(DEFAULT_COLOR)) + [1.0, 1.0, 1.0])[:3], 0, 1)
        mat = Material(
            name=mname,
            base_color=np.array([*kd, d.get("d", 1.0)], np.float32),
            metallic=d.get("pm", 0.0),
            roughness=d.get("pr", 1.0),
        )
        uv_transform = None
        if "map_kd" in d:
            fname, opts = d["map_kd"]
            mat.image = texture(fname, "map_Kd", mname, path)
            if mat.image is not None:
                mat.base_color[:3] = 1.0
                s = [float(x) for x in opts.get("-s", [])] + [1.0, 1.0]
                o = [float(x) for x in opts.get("-o", [])] + [0.0, 0.0]
                if s[:2] != [1.0, 1.0] or o[:2] != [0.0, 0.0]:
                    uv_transform = (np.array(s[:2], np.float32), np.array(o[:2], np.float32))
        for key, chan in (("map_pr", 1), ("map_pm", 2)):  # glTF layout: roughness in G, metallic in B
            img = texture(d[key][0], key.replace("map_p", "map_P"), mname, path) if key in d else None
            if img is None:
                continue
            if mat.metallic_roughness_image is None:
                mat.metallic_roughness_image = np.ones_like(img)
            elif img.shape != mat.metallic_roughness_image.shape:  # to the size of the first map
                img = image_to_array(array_to_pil(img).resize(mat.metallic_roughness_image.shape[1::-1]))
            mat.metallic_roughness_image[:, :, chan] = img[:, :, 0]
            setattr(mat, "roughness" if chan == 1 else "metallic", 1.0)
        key = next((k for k in ("norm", "map_bump", "bump") if k in d), None)
        img = texture(d[key][0], key, mname, path) if key else None
        if img is not None and np.ptp(img, axis=2).max() > 1e-3:  # a grey bump map is a height map: not used
            mat.normal_image = img
        out[mname] = (mat, uv_transform)
    return out


#: MTL texture options and how many arguments each takes (at most)
_TEX_OPTION_ARGS = dict.fromkeys(
    ("-blendu", "-blendv", "-bm", "-boost", "-cc", "-clamp", "-imfchan", "-texres", "-type"), 1
)
_TEX_OPTION_ARGS.update({"-mm": 2, "-o": 3, "-s": 3, "-t": 3})


def parse_tex_line(rest: str):
    """``[options] filename`` of an MTL map line → (filename, {option: [args]}): an option's first argument is taken
    as it is, further ones only while they are numbers; the last token always belongs to the filename."""
    tokens, opts = rest.split(), {}
    while len(tokens) > 1 and tokens[0].lower() in _TEX_OPTION_ARGS:
        opt = tokens.pop(0).lower()
        args = opts[opt] = []
        while len(args) < _TEX_OPTION_ARGS[opt] and len(tokens) > 1 and (not args or _is_number(tokens[0])):
            args.append(tokens.pop(0))
    return " ".join(tokens), opts


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def load_texture(ref: str, what: str, mname: str, mtl: Path, *, max_size, cache: dict, scope: Scope):
    """The image an MTL map line names, as an array, each file decoded once (``cache``: materials often share an
    atlas); ``None`` with a warning if it is missing or unreadable."""
    from PIL import Image

    owner = f"{what} of material '{mname}' in '{mtl.name}'"
    path = resolve_asset(ref, mtl.parent, scope, f"the {what} texture of material '{mname}' in '{mtl.name}'")
    if path is None:
        if ("missing", ref) not in cache:  # once per file: an exporter's absolute path is often in every material
            cache[("missing", ref)] = None
            warn(
                f"texture file '{ref}' ({owner}, and any other material that names it) was not found (looked in "
                f"'{mtl.parent}'); using the material colour instead: put the image next to the .mtl file or fix the path"
            )
        return None
    key = path.resolve()
    if key not in cache:
        try:
            with named_image_warnings(f"texture file '{path.name}' ({owner})"), Image.open(path) as img:
                cache[key] = image_to_array(img, max_size)
        except Exception as exc:  # corrupt / unsupported image: warn and fall back
            cache[key] = None
            warn(
                f"texture file '{path.name}' ({owner}) could not be read ({type(exc).__name__}: {exc}); "
                "using the material colour instead: re-save the image as PNG or JPEG"
            )
    return cache[key]
