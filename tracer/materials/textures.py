"""Mitsuba's `checkerboard` and `bitmap` textures as a diffuse reflectance: their host description, their
per-material table and the lookup in the kernel (tracer/bitmap.py reads the images)."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float, UInt32

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
