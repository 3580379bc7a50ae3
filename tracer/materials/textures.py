"""Mitsuba's `checkerboard` and `bitmap` textures as a diffuse reflectance: their host description, their
per-material table and the lookup in the kernel (tracer/bitmap.py reads the images)."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..bitmap import BitmapError, read_bitmap
from ..jit import Array3f, Bool, Float, UInt32
from ..spectra import rgb
from .reading import check_unit_interval

PLUGINS = {"checkerboard": ("color0", "color1", "to_uv"),
           "bitmap": ("filename", "bitmap", "data", "raw", "filter_type", "wrap_mode", "to_uv", "format", "accel")}
FIELDS = 18         # per material: kind, two colours, to_uv's two rows, a bitmap's offset, size and modes
IDENTITY_UV = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class Checkerboard:
    """Mitsuba's `checkerboard` texture: with (u', v') = to_uv (u, v), color0 where the fractional parts of u'
    and v' are both above 1/2 or both not, color1 elsewhere."""

    color0: tuple[float, float, float] = (0.4, 0.4, 0.4)
    color1: tuple[float, float, float] = (0.2, 0.2, 0.2)
    to_uv: tuple[tuple[float, float, float], ...] = IDENTITY_UV


@dataclass(frozen=True, eq=False)
class Bitmap:
    """Mitsuba's `bitmap` texture (tracer/bitmap.py): a linear RGB image looked up at to_uv (u, v)."""

    image: np.ndarray                      # (H, W, 3) float32
    to_uv: tuple[tuple[float, float, float], ...] = IDENTITY_UV
    bilinear: bool = True
    repeat: bool = True                    # else clamp


def from_xml(ctx, props, node) -> Checkerboard | Bitmap:
    if node.attrib.get("type") == "bitmap":
        return _bitmap(ctx, node, props)
    colours = [props.colour(name, d) for name, d in (("color0", 0.4), ("color1", 0.2))]
    m = props.get("to_uv", np.eye(4), ("transform",))
    props.finish()
    for name, c in zip(("color0", "color1"), colours):
        check_unit_interval(ctx, node, name, c)
    return Checkerboard(rgb(colours[0]), rgb(colours[1]), _to_uv(m))


def _to_uv(m: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    """A 4x4 transform acts on (u, v) through its x, y rows and columns and its translation (Mitsuba's
    conversion of a 4x4 to a 3x3 transform)."""
    return tuple(tuple(float(x) for x in row) for row in m[np.ix_([0, 1, 3], [0, 1, 3])])


def _bitmap(ctx, node, props) -> Bitmap:
    filename = props.get("filename", None, ("string",))
    raw = props.get("raw", False, ("boolean",))
    choices = {"filter_type": ("bilinear", "nearest"), "wrap_mode": ("repeat", "clamp"), "format": ("auto",)}
    modes = {}
    for name, accepted in choices.items():
        modes[name] = props.get(name, accepted[0], ("string",)).lower()
        if modes[name] not in accepted:
            raise ctx.error(props.values[name], f"{name} '{modes[name]}' unsupported; supported: {', '.join(accepted)}")
    m = props.get("to_uv", np.eye(4), ("transform",))
    props.ignore("accel")                  # how lookups are accelerated, not their values
    props.finish()
    if filename is None:
        raise ctx.error(node, "bitmap needs a <string name=\"filename\">")
    file = ctx.resolve(filename)
    if not file.is_file():
        raise ctx.error(node, f"image '{filename}' not found (looked in {', '.join(map(str, ctx.resolver))})")
    try:
        image = read_bitmap(file, raw)
    except BitmapError as e:
        raise ctx.error(node, str(e)) from None
    return Bitmap(image, _to_uv(m), modes["filter_type"] == "bilinear", modes["wrap_mode"] == "repeat")


class TextureTables:
    """Per material its texture (kind 0: none, 1: checkerboard, 2: bitmap) and every bitmap's texels."""

    def __init__(self, materials: list):
        rows = np.zeros((len(materials), FIELDS))
        texels = [np.zeros(3, np.float32)]
        offset = 1
        for i, b in enumerate(materials):
            t = b.texture
            if isinstance(t, Checkerboard):
                rows[i, :13] = [1.0, *t.color0, *t.color1, *np.asarray(t.to_uv)[:2].ravel()]
            elif isinstance(t, Bitmap):
                h, w = t.image.shape[:2]
                rows[i] = [2.0, 0, 0, 0, 0, 0, 0, *np.asarray(t.to_uv)[:2].ravel(), offset, w, h, t.bilinear, t.repeat]
                texels.append(t.image.ravel())
                offset += h * w
        self.rows = Float(rows.ravel())
        self.texels = Float(np.concatenate(texels))
        self.bitmaps = any(isinstance(b.texture, Bitmap) for b in materials)

    def reflectance(self, material: UInt32, uv: tuple[Float, Float], rho: Array3f, active: Bool) -> Array3f:
        """The texture's value at uv where the material has one (rho elsewhere)."""
        t = [dr.gather(Float, self.rows, material * FIELDS + k, active) for k in range(FIELDS)]
        u, v = uv
        tu = dr.fma(t[7], u, dr.fma(t[8], v, t[9]))
        tv = dr.fma(t[10], u, dr.fma(t[11], v, t[12]))
        first = (tu - dr.floor(tu) > 0.5) == (tv - dr.floor(tv) > 0.5)
        texture = dr.select(first, Array3f(t[1], t[2], t[3]), Array3f(t[4], t[5], t[6]))
        if self.bitmaps:
            texture = dr.select(t[0] > 1.5, self._bitmap(t, tu, tv, active & (t[0] > 1.5)), texture)
        return dr.select(t[0] > 0, texture, rho)

    def _bitmap(self, t: list[Float], u: Float, v: Float, active: Bool) -> Array3f:
        """A bitmap texture's texels around (u, v), filtered and wrapped (tracer/bitmap.py)."""
        offset, w, h, bilinear, repeat = t[13], t[14], t[15], t[16] > 0, t[17] > 0

        def wrap(i: Float, n: Float) -> UInt32:
            return UInt32(dr.select(repeat, i - n * dr.floor(i / n), dr.clip(i, 0.0, n - 1.0)))

        def texel(i: Float, j: Float) -> Array3f:
            index = UInt32(offset) + wrap(j, h) * UInt32(w) + wrap(i, w)
            return dr.gather(Array3f, self.texels, index, active)

        x = dr.select(bilinear, dr.fma(u, w, -0.5), u * w)
        y = dr.select(bilinear, dr.fma(v, h, -0.5), v * h)
        x0, y0 = dr.floor(x), dr.floor(y)
        wx, wy = dr.select(bilinear, x - x0, 0.0), dr.select(bilinear, y - y0, 0.0)
        top = texel(x0, y0) * (1.0 - wx) + texel(x0 + 1.0, y0) * wx
        bottom = texel(x0, y0 + 1.0) * (1.0 - wx) + texel(x0 + 1.0, y0 + 1.0) * wx
        return top * (1.0 - wy) + bottom * wy
