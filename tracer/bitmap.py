"""Mitsuba's `bitmap` texture on the host: the image as linear RGB (the kernel lookup is in tracer/materials/textures.py).

As Mitsuba 3.9.1's RGB variants: an 8-bit image (PNG, JPEG, BMP, ...; read with Pillow) is sRGB-encoded
unless `raw`, and each texel is decoded to linear before filtering; an OpenEXR image is linear. Alpha is
dropped, a grey image is grey in all three channels. The lookup at texture coordinates (u, v) is
texel-centred (x = u W - 1/2, y = v H - 1/2, row 0 at v = 0), bilinear or nearest, wrapped by repeating or
clamping.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .imageio import ImageError, read_exr_rgb


class BitmapError(ValueError):
    pass


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), on values in [0, 1]."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def read_bitmap(path: Path, raw: bool) -> np.ndarray:
    """(H, W, 3) float32 linear RGB."""
    if path.suffix.lower() == ".exr":
        try:
            return read_exr_rgb(path)
        except ImageError as e:
            raise BitmapError(str(e)) from None
    from PIL import Image

    try:
        _check_png_chunks(path)
        with Image.open(path) as im:
            if im.mode not in ("RGB", "RGBA", "L", "LA", "P"):
                raise BitmapError(f"{path}: pixel format {im.mode} unsupported; supported: 8-bit RGB, RGBA, grey")
            pixels = np.asarray(im.convert("RGB"), np.float64) / 255.0
    except BitmapError:
        raise
    except Exception as e:   # whatever Pillow raises on a truncated or corrupted file (OSError, SyntaxError, ...)
        raise BitmapError(f"{path}: not a readable image ({type(e).__name__}: {e})") from None
    return (pixels if raw else srgb_to_linear(pixels)).astype(np.float32)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _check_png_chunks(path: Path) -> None:
    """Refuses, as libpng (Mitsuba's reader) does by default, a PNG whose critical chunks (IHDR, PLTE, IDAT,
    IEND) fail their CRC-32 (PNG spec, section 5.3) or that ends before its image data does; Pillow checks
    neither the image data's CRCs nor, always, its end."""
    import zlib

    data = path.read_bytes()
    if not data.startswith(PNG_SIGNATURE):
        return
    at, seen = len(PNG_SIGNATURE), set()
    while at + 12 <= len(data):
        length = int.from_bytes(data[at:at + 4], "big")
        kind, body = data[at + 4:at + 8], data[at + 8:at + 8 + length]
        crc = data[at + 8 + length:at + 12 + length]
        if len(crc) < 4:             # cut inside this chunk: libpng fails unless the image data was all read
            if kind == b"IDAT" or b"IDAT" not in seen:
                break
            return
        seen.add(kind)
        critical = kind[:1].isupper()     # an ancillary chunk's bad CRC: libpng warns and skips the chunk
        if critical and zlib.crc32(kind + body).to_bytes(4, "big") != crc:
            raise BitmapError(f"{path}: not a readable image (PNG chunk {kind.decode('latin-1')!r} fails its CRC: "
                              "corrupted)")
        if kind == b"IEND":
            return
        at += 12 + length
    if b"IDAT" not in seen or data[at + 4:at + 8] == b"IDAT":     # cut before or inside the image data
        raise BitmapError(f"{path}: not a readable image (a truncated PNG: it ends inside its image data)")
