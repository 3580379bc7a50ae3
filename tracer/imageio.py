"""Writing images: linear float32 RGB OpenEXR and sRGB PNG, chosen by the file's extension.

Every file is written to a temporary beside its target and moved into place (os.replace): a failure
leaves no partial file and the previous file intact. `Outputs` does so for a set of files, moving them
only once all were written. Files are created with the mode the umask gives (0666 & ~umask), as any
program's `open` would.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenEXR


from .errors import OutputError, UserError, clip

PNG_ROWS = 256  # rows encoded at once: the sRGB encoding holds a band's floats, not the image's


class ImageError(UserError, ValueError):
    """An image that cannot be written as asked (NaN, negative radiance, an unknown format)."""


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


def _temporary(path: Path) -> Path:
    """A new empty file beside `path`, created with the umask's mode (O_EXCL: never an existing one)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{os.urandom(4).hex()}.tmp{path.suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"{path}: no free temporary name beside it")


def atomic_write(path: str | Path, write) -> None:
    """`write(temporary_name)` and then the temporary moved onto `path`: `path` is either the old file or the
    complete new one, never a partial file, and has the umask's mode."""
    tmp = _temporary(Path(path))
    try:
        write(str(tmp))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def probe_writable(path: str | Path) -> None:
    """Refuses, before any work, an output path whose folder cannot be created or written: a probe file
    is created there and removed. The message names `path`."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, not an image file")
    folder = next(p for p in path.absolute().parents if p.exists())
    if not folder.is_dir():
        raise OutputError(f"{path}: cannot write into {path.parent}: {folder} is a file, not a folder")
    try:
        _temporary(path).unlink()
    except OSError as e:
        raise OutputError(f"{path}: cannot write into {path.parent}: {e.strerror or e}") from None


def write_exr(path: str | Path, image: np.ndarray, metadata: dict[str, str] | None = None) -> None:
    """Linear float32 RGB; `metadata` becomes string attributes of the header (the render's spp, seed)."""
    check_image(image, str(path))
    _write_rgb_exr(Path(path), image, metadata)


def write_normal_exr(path: str | Path, normal: np.ndarray) -> None:
    """A normal image, whose components lie in [-1, 1] (OIDN reads them so, not remapped to [0, 1])."""
    if not np.isfinite(normal).all() or np.abs(normal).max(initial=0.0) > 1.0:
        raise ImageError(f"{path}: a normal image must be finite and lie in [-1, 1]")
    _write_rgb_exr(Path(path), normal)


def _write_rgb_exr(path: Path, image: np.ndarray, metadata: dict[str, str] | None = None) -> None:
    rgb = np.ascontiguousarray(image, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({key: str(value) for key, value in (metadata or {}).items()})

    def write(tmp):
        with OpenEXR.File(header, {"RGB": rgb}) as f:
            f.write(tmp)

    atomic_write(path, write)


def read_exr_header(path: str | Path) -> dict:
    with OpenEXR.File(str(path)) as f:
        return dict(f.header())


def _rgb_pixels(path: str | Path) -> np.ndarray:
    """The RGB channels of an OpenEXR file's first part as stored (an alpha channel is dropped, as Mitsuba's
    conversion to RGB does)."""
    with OpenEXR.File(str(path)) as f:
        channels = f.parts[0].channels
        if "RGB" in channels or "RGBA" in channels:
            return np.asarray(channels.get("RGB", channels.get("RGBA")).pixels)[..., :3]
        if all(c in channels for c in "RGB"):
            return np.stack([np.asarray(channels[c].pixels) for c in "RGB"], axis=-1)
        raise ImageError(f"{path}: no R, G, B channels (has {', '.join(channels)})")


def read_exr(path: str | Path) -> np.ndarray:
    """An image the tracer or a compared renderer wrote, as (H, W, 3) float32."""
    return _rgb_pixels(path).astype(np.float32)


# The attributes every OpenEXR header predefines, with their types: OpenEXR's C++ library (Mitsuba's reader)
# refuses a file that gives one of them another type; its Python binding reads the pixels regardless.
PREDEFINED = {b"channels": b"chlist", b"compression": b"compression", b"dataWindow": b"box2i",
              b"displayWindow": b"box2i", b"lineOrder": b"lineOrder", b"pixelAspectRatio": b"float",
              b"screenWindowCenter": b"v2f", b"screenWindowWidth": b"float"}


def _check_attribute_types(path: Path) -> None:
    """The first header's predefined attributes have their types (OpenEXR file layout: magic, version, then
    name, type, size and value of each attribute until an empty name)."""
    with open(path, "rb") as f:
        data = f.read(1 << 16)
    at = 8
    while at < len(data) and data[at] != 0:
        name_end = data.find(b"\0", at)
        type_end = data.find(b"\0", name_end + 1)
        if name_end < 0 or type_end < 0 or type_end + 4 > len(data):
            return                                # a long or truncated header: OpenEXR reports it
        name, kind = data[at:name_end], data[name_end + 1:type_end]
        if name in PREDEFINED and kind != PREDEFINED[name]:
            raise ImageError(f"{path}: not a readable OpenEXR image (attribute '{name.decode('latin-1')}' has type "
                             f"'{clip(kind.decode('latin-1'))}', not '{PREDEFINED[name].decode()}')")
        at = type_end + 5 + int.from_bytes(data[type_end + 1:type_end + 5], "little", signed=True)


def read_exr_rgb(path: Path) -> np.ndarray:
    """An input image (an environment map, a texture) as (H, W, 3) float32: readable, finite, non-negative."""
    try:
        _check_attribute_types(path)
        image = _rgb_pixels(path).astype(np.float32)
    except ImageError:
        raise
    except Exception as e:   # whatever OpenEXR raises on a truncated or corrupted file (RuntimeError, IndexError)
        raise ImageError(f"{path}: not a readable OpenEXR image ({type(e).__name__}: {e})") from None
    if image.ndim != 3 or not image.size:
        raise ImageError(f"{path}: an OpenEXR image of no pixels")
    if not np.all(np.isfinite(image)) or np.any(image < 0):
        raise ImageError(f"{path}: pixels must be finite and non-negative")
    return image


def write_png(path: str | Path, image: np.ndarray, metadata: dict[str, str] | None = None) -> None:
    """sRGB, 8 bits per channel, `metadata` as text chunks; encoded band by band (PNG_ROWS) to bound the
    encoding's memory. (Pillow imported here: a render that writes no PNG does not pay its import.)"""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    check_image(image, str(path))
    pixels = np.empty(image.shape, dtype=np.uint8)
    for top in range(0, image.shape[0], PNG_ROWS):
        pixels[top:top + PNG_ROWS] = np.round(srgb_encode(image[top:top + PNG_ROWS]) * 255)
    info = PngInfo()
    for key, value in (metadata or {}).items():
        info.add_text(key, str(value))
    atomic_write(Path(path), lambda tmp: Image.fromarray(pixels, "RGB").save(tmp, format="PNG", pnginfo=info))


WRITERS: dict[str, Callable] = {".exr": write_exr, ".png": write_png}


def writer(path: str | Path) -> Callable:
    """The writer of `path`'s format, by its extension in any case; OutputError for another."""
    suffix = Path(path).suffix.lower()
    if suffix not in WRITERS:
        raise OutputError(f"{path}: unknown image format '{Path(path).suffix}'; the tracer writes "
                          f"{' and '.join(WRITERS)} (linear OpenEXR, 8-bit sRGB PNG)")
    return WRITERS[suffix]


class Outputs:
    """Files written together or not at all: `add` writes each to a temporary beside its target,
    `commit` moves them all into place; `discard` (or a failed `add`) removes the temporaries, leaving
    the previous files as they were. Use as a context manager: leaving it by an exception discards."""

    def __init__(self):
        self.staged: list[tuple[Path, Path]] = []

    def add(self, path: str | Path, write: Callable[[str, np.ndarray], None], image: np.ndarray, **kw) -> None:
        path = Path(path)
        tmp = _temporary(path)
        self.staged.append((tmp, path))
        write(str(tmp), image, **kw)

    def commit(self) -> list[Path]:
        for tmp, path in self.staged:
            os.replace(tmp, path)
        done, self.staged = [path for _, path in self.staged], []
        return done

    def discard(self) -> None:
        for tmp, _ in self.staged:
            tmp.unlink(missing_ok=True)
        self.staged = []

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        self.discard()
