"""PNG previews of HDR images: exposure, clamp, sRGB transfer curve, 8 bits.

The PNG goes through OpenImageIO when it is installed and through a small built-in zlib
writer otherwise, so previews never need an optional dependency.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from .. import _checks
from .._arrays import numeric
from .._typing import FloatArray
from .atomic import atomic_write

__all__ = ["tonemap_srgb", "write_preview", "encode_png"]


def tonemap_srgb(image: FloatArray, *, exposure: float = 0.0) -> np.ndarray:
    """Linear HDR (H, W[, C]) to 8-bit sRGB: scale by ``2**exposure``, clamp, encode, round.

    NaN becomes 0 and +Inf becomes white, so a preview can always be written.

    Examples
    --------
    >>> tonemap_srgb(np.array([[[0.0, 0.5, 1.0]]]))[0, 0].tolist()
    [0, 188, 255]
    """
    a = numeric("image", image).astype(np.float64)  # complex, bool, object, masked entries refused
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise ValueError(f"image: expected (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {np.shape(image)}")
    exposure = _checks.real("exposure", exposure)
    # 2**1023 already saturates every positive float; beyond it the scale itself would overflow.
    with np.errstate(over="ignore"):
        x = np.nan_to_num(a * 2.0 ** min(float(exposure), 1023.0), nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    encoded = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    if a.shape[2] == 4:  # alpha is linear coverage, not a colour
        encoded[..., 3] = x[..., 3]
    return np.rint(encoded * 255.0).astype(np.uint8)


def encode_png(pixels: np.ndarray) -> bytes:
    """Encode (H, W, C) uint8 pixels (C in 1, 3, 4) as a PNG file (zlib, no filtering)."""
    p = np.ascontiguousarray(pixels, dtype=np.uint8)
    h, w, c = p.shape
    colour_type = {1: 0, 3: 2, 4: 6}[c]
    # Every scanline starts with filter type 0 (None).
    raw = np.concatenate([np.zeros((h, 1), np.uint8), p.reshape(h, w * c)], axis=1).tobytes()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")


_LIBPNG_LIMIT = 1_000_000  # libpng's default user limit on width and height


_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the empty IEND chunk every PNG ends with


def _ends_whole(path: str) -> bool:
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        if fh.tell() < len(_IEND):
            return False
        fh.seek(-len(_IEND), os.SEEK_END)
        return fh.read() == _IEND


def _write_png(tmp: str, pixels: np.ndarray) -> None:
    # OpenImageIO's write of a strided array (an RGBA preview's view of its planes) failed in libpng, which printed
    # "No IDATs written into file" on stderr, -q or not, before the encoder below wrote it again (an attack pass).
    pixels = np.ascontiguousarray(pixels)
    try:
        import OpenImageIO as oiio  # the optional ``exr`` extra; the built-in encoder below does without
    except ImportError:
        oiio = None
    h, w, c = pixels.shape
    # libpng refuses more than 10**6 pixels a side by default, and says so on stderr: the built-in
    # encoder writes those without a word.
    if oiio is not None and max(h, w) <= _LIBPNG_LIMIT:
        out = oiio.ImageOutput.create("png")
        if out is not None and out.open(tmp, oiio.ImageSpec(w, h, c, oiio.UINT8)):
            ok = out.write_image(pixels)
            ok = out.close() and ok
            # A short write (a full disk) shows in geterror() at most: write_image() and close() said True, and a
            # cut preview was committed (a red-team pass). Whole, the file ends with its IEND chunk; otherwise the
            # encoder below writes it again, and raises if it cannot.
            if ok and not out.geterror() and _ends_whole(tmp):
                return
    with open(tmp, "wb") as fh:
        fh.write(encode_png(pixels))


def write_preview(path: str | os.PathLike[str], image: FloatArray, *, exposure: float = 0.0,
                  overwrite: bool = False) -> Path:
    """Write an sRGB PNG preview of a linear HDR image, atomically.

    Parameters
    ----------
    path
        Target ``.png`` file.
    image
        (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) linear values.
    exposure
        Stops: the image is multiplied by ``2**exposure`` before clamping to [0, 1].
    overwrite
        Replace an existing file.
    """
    pixels = tonemap_srgb(image, exposure=exposure)
    return atomic_write(path, lambda tmp: _write_png(tmp, pixels), overwrite=overwrite)
