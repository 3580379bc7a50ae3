"""Mitsuba's `envmap` emitter on the host: the latitude-longitude image and the distribution shadow rays
towards it are drawn from, and the kernel that looks it up and samples it.

Radiance (Mitsuba 3.9's RGB variants): a world direction d is taken to the map's frame, v = to_world^-1 d,
and to u = atan2(v.x, -v.z) / 2 pi (wrapped to [0, 1)), t = acos(v.y) / pi; the image is interpolated
bilinearly, texel-centred and periodic in u, with rows at t = j / (H - 1) (clamped), and scaled by `scale`.

Sampling (the tracer's own; any density that is positive wherever the map is makes the estimate
unbiased): with probability MIX_UNIFORM a direction uniform on the sphere, otherwise a cell of the W x H
(u, t) grid with probability proportional to its texel's luminance times sin(theta), then a point uniform
in the cell.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..imageio import ImageError, read_exr_rgb
from ..jit import Array3f, Float, UInt32, gather_vec3, row_table
from ..sampling import GuidedCDF, square_to_uniform_sphere

PLUGINS = {"envmap": ("filename", "bitmap", "scale", "to_world", "mis_compensation", "sampling_weight")}
ENVIRONMENT = True    # at most one environment emitter per scene
MIX_UNIFORM = 0.1
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])   # Rec. 709 Y, as Mitsuba's luminance()


@dataclass(eq=False)
class EnvironmentMap:
    """Mitsuba's `envmap`: a latitude-longitude image of radiance (already times `scale`) around the scene,
    turned by `to_world`."""

    image: np.ndarray          # (H, W, 3) float32 linear RGB
    to_world: np.ndarray
    name: str = ""
    sampling_weight: float = 1.0       # Mitsuba's: relative to the other lights' (lights.choice)


def from_xml(ctx, props, node) -> EnvironmentMap:
    """Mitsuba's `envmap` from an OpenEXR file."""
    filename = props.get("filename", None, ("string",))
    scale = props.get("scale", 1.0, ("float", "integer"))
    to_world = props.get("to_world", np.eye(4), ("transform",))
    props.ignore("mis_compensation")    # where it is sampled, not the estimate
    weight = props.sampling_weight()
    props.finish()
    if filename is None:
        raise ctx.error(node, "envmap needs a <string name=\"filename\"> (an OpenEXR image)")
    if not filename.lower().endswith(".exr"):
        raise ctx.error(props.values["filename"], f"envmap '{filename}': only OpenEXR images are supported")
    linear = to_world[:3, :3]
    if not np.allclose(linear.T @ linear, np.eye(3), atol=1e-5):
        raise ctx.error(node, "an envmap's to_world must be a rotation (no scale or shear)")
    if scale < 0:
        raise ctx.error(node, f"scale must be non-negative, got {scale}")
    file = ctx.resolve(filename)
    if not file.is_file():
        raise ctx.error(node, f"image '{filename}' not found (looked in {', '.join(map(str, ctx.resolver))})")
    try:
        image = read_exr_rgb(file)
    except ImageError as e:
        raise ctx.error(node, str(e)) from None
    with np.errstate(over="ignore"):
        radiance = image * np.float32(scale)
    if not np.all(np.isfinite(radiance)):
        raise ctx.error(node, f"scale {scale:g} times the image's largest value {image.max():g} overflows float32")
    return EnvironmentMap(radiance, to_world, node.attrib.get("id", f"envmap@{node.line}"), weight)


@dataclass(frozen=True)
class Distribution:
    """The sampling tables: row CDF (H), per-row CDFs (H x W) and cell probabilities (H x W)."""

    row_cdf: np.ndarray
    col_cdf: np.ndarray
    cell_p: np.ndarray
    mix_uniform: float


def distribution(image: np.ndarray) -> Distribution:
    h, w, _ = image.shape
    sin_theta = np.sin(np.pi * (np.arange(h) + 0.5) / h)
    weight = (image.astype(float) @ LUMINANCE).clip(min=0) * sin_theta[:, None]
    total = weight.sum()
    if not total > 0:        # a black map: uniform directions only
        return Distribution(np.linspace(1 / h, 1, h), np.tile(np.linspace(1 / w, 1, w), (h, 1)),
                            np.full((h, w), 1.0 / (h * w)), 1.0)
    cell_p = weight / total
    row_p = cell_p.sum(axis=1)
    row_cdf = np.cumsum(row_p)
    col_cdf = np.cumsum(cell_p, axis=1) / np.where(row_p > 0, row_p, 1.0)[:, None]
    row_cdf[-1] = 1.0
    col_cdf[:, -1] = 1.0
    return Distribution(row_cdf, col_cdf, cell_p, MIX_UNIFORM)


class EnvmapKernel:
    """An `envmap` emitter in the kernel: radiance by direction, and the density and sampling of
    the distribution above (the map's tables gathered from; its frame as literals)."""

    def __init__(self, env):
        self.h, self.w = env.image.shape[:2]
        self.texels = row_table(np.asarray(env.image, np.float32))
        linear = env.to_world[:3, :3]
        self.to_world, self.to_local = linear, np.linalg.inv(linear)
        dist = distribution(env.image)
        self.mix = dist.mix_uniform
        self.rows, self.cols = GuidedCDF(dist.row_cdf.astype(np.float32)), GuidedCDF(dist.col_cdf.astype(np.float32))
        self.cell_p = Float(dist.cell_p.astype(np.float32).ravel())

    def _local(self, d: Array3f) -> Array3f:
        m = self.to_local
        return Array3f(*(d.x * float(m[r, 0]) + d.y * float(m[r, 1]) + d.z * float(m[r, 2]) for r in range(3)))

    def _uv(self, v: Array3f) -> tuple[Float, Float]:
        u = dr.atan2(v.x, -v.z) * (0.5 / dr.pi)
        return u - dr.floor(u), dr.clip(dr.safe_acos(v.y) / dr.pi, 0.0, 1.0)

    def _texel(self, i: UInt32, j: UInt32) -> Array3f:
        return gather_vec3(self.texels, j * self.w + i)

    def radiance(self, d: Array3f) -> Array3f:
        u, t = self._uv(self._local(d))
        x = u * self.w - 0.5                              # texel-centred, periodic in u
        x0 = dr.floor(x)
        wx = x - x0
        i0 = UInt32(dr.select(x0 < 0, x0 + self.w, x0))
        i1 = dr.select(i0 + 1 >= self.w, i0 + 1 - self.w, i0 + 1)
        y = t * (self.h - 1)                              # rows at t = j / (H - 1)
        j0 = dr.minimum(UInt32(dr.floor(y)), self.h - 1)
        j1 = dr.minimum(j0 + 1, self.h - 1)
        wy = y - Float(j0)
        top = self._texel(i0, j0) * (1.0 - wx) + self._texel(i1, j0) * wx
        bottom = self._texel(i0, j1) * (1.0 - wx) + self._texel(i1, j1) * wx
        return top * (1.0 - wy) + bottom * wy

    def pdf(self, d: Array3f) -> Float:
        v = self._local(d)
        u, t = self._uv(v)
        i = dr.minimum(UInt32(u * self.w), self.w - 1)
        j = dr.minimum(UInt32(t * self.h), self.h - 1)
        sin_theta = dr.maximum(dr.safe_sqrt(1.0 - dr.square(v.y / dr.norm(v))), 1e-7)
        p_cells = dr.gather(Float, self.cell_p, j * self.w + i) * (self.w * self.h / (2.0 * dr.pi * dr.pi))
        return self.mix / (4.0 * dr.pi) + (1.0 - self.mix) * p_cells / sin_theta

    def sample(self, u1: Float, u2: Float) -> Array3f:
        uniform = u1 < self.mix
        s = dr.select(uniform, u1 / self.mix, (u1 - self.mix) / (1.0 - self.mix)) if self.mix < 1 else u1
        j, dt = self.rows.sample(s)
        i, du = self.cols.sample(u2, j)
        t, u = (Float(j) + dt) / self.h, (Float(i) + du) / self.w
        theta, phi = t * dr.pi, u * dr.two_pi
        sin_t, cos_t = dr.sincos(theta)
        sin_p, cos_p = dr.sincos(phi)
        m = self.to_world
        local = Array3f(sin_p * sin_t, cos_t, -cos_p * sin_t)
        d = dr.normalize(Array3f(*(local.x * float(m[r, 0]) + local.y * float(m[r, 1]) + local.z * float(m[r, 2])
                                   for r in range(3))))
        return dr.select(uniform, square_to_uniform_sphere(s, u2), d)
