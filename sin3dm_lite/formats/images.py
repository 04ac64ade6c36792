"""Images in and out: textures as ``(h, w, 3)`` float32 RGB in [0, 1] (:func:`image_to_array`), and back to 8-bit
pictures (:func:`array_to_pil`) or PNG bytes (:func:`png_bytes`), so the rounding lives in one place.
"""

from __future__ import annotations

import io
import warnings

import numpy as np

from .common import warn


class named_image_warnings:  # noqa: N801 (used as a function: ``with named_image_warnings(what):``)
    """Say PIL's ``DecompressionBombWarning`` (an image of more pixels than PIL trusts, read anyway) with the file
    it came from: ``what`` names it (``texture file 'a.png' (diffuse of material 'm' in 'x.mtl')``), once per
    image. Other warnings raised inside pass on as they were."""

    def __init__(self, what: str):
        self.what, self.catch = what, warnings.catch_warnings(record=True)

    def __enter__(self):
        from PIL import Image

        self.caught = self.catch.__enter__()
        warnings.simplefilter("always", Image.DecompressionBombWarning)
        return self

    def __exit__(self, *exc):
        from PIL import Image

        self.catch.__exit__(*exc)
        said = set()
        for w in self.caught:
            if not issubclass(w.category, Image.DecompressionBombWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
            elif str(w.message) not in said:  # the same image opened twice (checked, then read): said once
                said.add(str(w.message))
                warn(
                    f"{self.what} is a very large image ({w.message}); it is read and shrunk to the texture size: "
                    "if it is not meant to be this large, re-save it smaller"
                )
        return False


def image_to_array(image, max_size: int | None = None) -> np.ndarray:
    """A PIL image or array as ``(h, w, 3)`` float32 RGB in [0, 1]: alpha dropped, grey repeated into RGB, 16-bit
    and float images scaled, images larger than ``max_size`` (longest side) shrunk with a box filter."""
    from PIL import Image

    if isinstance(image, Image.Image):
        image.load()
        if image.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I", "F"):
            arr = np.asarray(image).astype(np.float32)
            if image.mode.startswith("I;16"):
                arr = arr / 65535.0
            elif image.mode == "I":  # 32-bit int: 16-bit data in practice, 8-bit if it fits
                arr = arr / (255.0 if arr.max(initial=0) <= 255 else 65535.0)
            image = Image.fromarray(np.ascontiguousarray(arr, np.float32))  # mode "F", resized below if needed
        elif image.mode != "RGB":
            image = image.convert("RGBA" if image.mode in ("P", "PA", "LA", "RGBa", "La") else "RGB")
        arr = np.asarray(shrink(image, max_size))
    else:
        arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"not an image: array of shape {arr.shape}")
    # pick the RGB channels first, then make one float32 copy (a 4096² texture is 200 MB per copy)
    arr = np.repeat(arr[:, :, :1], 3, axis=2) if arr.shape[2] in (1, 2) else arr[:, :, :3]  # grey (+ alpha)
    out = np.ascontiguousarray(arr, dtype=np.float32)
    if out is arr:
        out = out.copy()  # never scale the caller's array in place
    if arr.dtype in (np.uint8, np.uint16):
        out /= 255.0 if arr.dtype == np.uint8 else 65535.0
    elif arr.dtype != bool:
        np.nan_to_num(out, copy=False)
        np.clip(out, 0.0, 1.0, out=out)
    return out


def array_to_pil(image: np.ndarray, max_size: int | None = None, resample: str = "box"):
    """An ``(h, w[, c])`` image (floats in [0, 1], rounded in their own precision, or ``uint8``) as an 8-bit PIL
    image, shrunk to ``max_size`` (longest side) with the filter ``resample`` (``"box"`` or ``"bilinear"``)."""
    from PIL import Image

    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        arr = np.round(np.clip(arr, 0, 1) * 255).astype(np.uint8)
    return shrink(Image.fromarray(arr), max_size, resample)


def png_bytes(image: np.ndarray, max_size: int | None = None) -> bytes:
    """Encode an ``(h, w, 3|4)`` image (float in [0, 1] or uint8) as PNG without alpha, floats rounded in double
    precision, shrunk to ``max_size`` with a bilinear filter."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = img.astype(np.float64)
    buf = io.BytesIO()
    array_to_pil(img[..., :3] if img.ndim == 3 else img, max_size, resample="bilinear").save(buf, format="png")
    return buf.getvalue()


def shrink(img, max_size: int | None, resample: str = "box"):
    """A PIL image shrunk (``"box"`` or ``"bilinear"`` filter) so that its longest side is at most ``max_size``."""
    from PIL import Image

    if not max_size or max(img.size) <= max_size:
        return img
    s = max_size / max(img.size)
    filters = {"box": Image.BOX, "bilinear": Image.BILINEAR}
    return img.resize((max(1, round(img.width * s)), max(1, round(img.height * s))), filters[resample])
