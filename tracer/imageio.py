"""Writing images: linear float32 RGB OpenEXR and sRGB PNG, each atomically (no partial file)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image


class ImageError(ValueError):
    pass


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function on radiance clipped to [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def check_image(image: np.ndarray, what: str = "image") -> None:
    """Refuses NaN, infinity and negative radiance: a correct render has none."""
    bad = ~np.isfinite(image)
    if bad.any():
        raise ImageError(f"{what} holds {int(bad.any(axis=-1).sum())} pixels with NaN or infinite radiance")
    if (image < 0).any():
        raise ImageError(f"{what} holds {int((image < 0).any(axis=-1).sum())} pixels with negative radiance")


def _atomic(path: Path, write) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_exr(path: str | Path, image: np.ndarray) -> None:
    check_image(image, str(path))
    _write_rgb_exr(Path(path), image)


def write_normal_exr(path: str | Path, normal: np.ndarray) -> None:
    """A normal image, whose components lie in [-1, 1] (OIDN reads them so, not remapped to [0, 1])."""
    if not np.isfinite(normal).all() or np.abs(normal).max(initial=0.0) > 1.0:
        raise ImageError(f"{path}: a normal image must be finite and lie in [-1, 1]")
    _write_rgb_exr(Path(path), normal)


def _write_rgb_exr(path: Path, image: np.ndarray) -> None:
    rgb = np.ascontiguousarray(image, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def write(tmp):
        with OpenEXR.File(header, {"RGB": rgb}) as f:
            f.write(tmp)

    _atomic(path, write)


def read_exr(path: str | Path) -> np.ndarray:
    with OpenEXR.File(str(path)) as f:
        channels = f.channels()
        if "RGB" in channels:
            return np.asarray(channels["RGB"].pixels, dtype=np.float32)
        return np.stack([np.asarray(channels[c].pixels, np.float32) for c in "RGB"], axis=-1)


def write_png(path: str | Path, image: np.ndarray) -> None:
    check_image(image, str(path))
    pixels = np.round(srgb_encode(image) * 255).astype(np.uint8)
    _atomic(Path(path), lambda tmp: Image.fromarray(pixels, "RGB").save(tmp, format="PNG"))
