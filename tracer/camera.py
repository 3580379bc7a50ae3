"""Cameras with the conventions of Mitsuba's `perspective` (a pinhole), `thinlens` and `orthographic` sensors."""
from __future__ import annotations

import drjit as dr
import numpy as np

from .jit import Array3f, Float, PCG32, UInt32, opaque_f, opaque_u32, opaque_vec3
from .sampling import square_to_uniform_disk_concentric
from .scene import Camera


def primary_rays(camera: Camera, pixel: UInt32, rng: PCG32):
    """Rays through film positions jittered uniformly inside their pixel (pixel = y * width + x).

    Local +z looks forward, +x left and +y up, so pixel (0, 0) is the top-left one, as in Mitsuba. A thin
    lens (Mitsuba's `thinlens`) starts each ray at a point drawn uniformly on its disk (concentric map) and
    aims it at the pixel's point on the plane at focus_distance.
    Pixels are counted over the sampled grid, camera.sampled_size: the image and, with hdrfilm's
    sample_border, the filter's border around it. A crop window places the image inside the whole film,
    through which rays are cast (Mitsuba's projection of film size, crop size and crop offset).
    Returns (origin, direction, t_min, t_max, x, y): t_min/t_max are the near and far clip planes,
    (x, y) the image position in pixels, where the film splats the sample.
    """
    columns, border = opaque_u32(camera.sampled_size[0]), camera.border   # any resolution: the same kernel
    x = Float(pixel % columns) + rng.next_float32() - border
    y = Float(pixel // columns) + rng.next_float32() - border
    fx, fy = x + camera.crop_x, y + camera.crop_y        # on the whole film
    width, height = camera.film_size
    if camera.projection == "orthographic":
        return _orthographic(camera, fx, fy) + (x, y)
    tan_x, tan_y = (opaque_f(t) for t in camera.tan_half_fov())
    local = Array3f((1.0 - 2.0 * fx * _reciprocal(width)) * tan_x, (1.0 - 2.0 * fy * _reciprocal(height)) * tan_y, 1.0)
    axes, origin = _pose(camera.to_world)
    if camera.aperture_radius > 0:     # a thin lens: through a point of its disk towards the focal plane's point
        lx, ly = square_to_uniform_disk_concentric(rng.next_float32(), rng.next_float32())
        radius = opaque_f(camera.aperture_radius)
        lens = Array3f(lx * radius, ly * radius, 0.0)
        local = local * opaque_f(camera.focus_distance) - lens
    local = dr.normalize(local)
    d = dr.normalize(axes[0] * local.x + axes[1] * local.y + axes[2] * local.z)
    o = origin + Array3f(0.0) * local.x  # broadcast to the wavefront's width
    if camera.aperture_radius > 0:
        o += axes[0] * lens.x + axes[1] * lens.y
    inv_z = dr.rcp(local.z)
    return o, d, opaque_f(camera.near_clip) * inv_z, opaque_f(camera.far_clip) * inv_z, x, y


def _pose(m: np.ndarray) -> tuple[list[Array3f], Array3f]:
    """to_world's axes (its first three columns) and origin as run-time constants (jit.opaque_f; nothing
    folded, a camera's arithmetic being once per ray): every viewpoint runs the same kernel."""
    return [opaque_vec3(m[:3, k]) for k in range(3)], opaque_vec3(m[:3, 3])


def _reciprocal(size: float) -> Float:
    """1 / size in single precision, as a run-time constant: x * _reciprocal(size) is what Dr.Jit makes of
    x / size with size a literal (a product with the literal's reciprocal), with the size out of the kernel."""
    return opaque_f(np.float32(1.0) / np.float32(size))


def _orthographic(camera: Camera, x: Float, y: Float):
    """Mitsuba's `orthographic` sensor: parallel rays along to_world's +z from the point (1 - 2 x / width,
    (1 - 2 y / height) / aspect, near_clip) (x, y on the whole film) of the local near plane (its orthographic_projection inverted;
    to_world may scale it), reaching far_clip - near_clip beyond it."""
    width, height = camera.film_size
    aspect = width / height
    m = camera.to_world
    lx, ly = 1.0 - 2.0 * x * _reciprocal(width), (1.0 - 2.0 * y * _reciprocal(height)) * _reciprocal(aspect)
    o = opaque_vec3(m[:3, 0]) * lx + opaque_vec3(m[:3, 1]) * ly + opaque_vec3(m[:3, 2] * camera.near_clip + m[:3, 3])
    d = opaque_vec3(m[:3, 2] / np.linalg.norm(m[:3, 2])) + Array3f(0.0) * lx   # broadcast to the wavefront's width
    return o, d, Float(0.0), opaque_f(camera.far_clip - camera.near_clip)


def pixel_count(camera: Camera) -> int:
    """The pixels camera rays start in (camera.sampled_size)."""
    return int(np.prod(camera.sampled_size))
