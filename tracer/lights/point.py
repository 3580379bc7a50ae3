"""Mitsuba's `point`, `spot` and `projector` emitters: delta lights at a position, the last two with an
intensity that varies with direction (a cone's falloff, a projected image)."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array3f, Float, UInt32, vec3
from ..materials import Bitmap
from ..materials.textures import TextureTables
from ..spectra import rgb
from .sample import POINT_LIGHT, LightSample

PLUGINS = {"point": ("position", "to_world", "intensity", "sampling_weight"),
           "spot": ("to_world", "intensity", "cutoff_angle", "beam_width", "texture", "sampling_weight"),
           "projector": ("to_world", "irradiance", "scale", "fov", "fov_axis", "focal_length", "sampling_weight")}
ENVIRONMENT = False


@dataclass(eq=False)
class PointLight:
    """Mitsuba's `point` emitter: `intensity` (radiant intensity) from `position` in every direction; with
    `spot` = (axis, cutoff_angle, beam_width) in degrees, Mitsuba's `spot`: full intensity within beam_width
    of the axis, falling linearly in angle to 0 at cutoff_angle."""

    position: np.ndarray
    intensity: tuple[float, float, float]
    name: str = ""
    spot: tuple[np.ndarray, float, float] | None = None
    image: Bitmap | None = None        # a spot's projected texture, a projector's irradiance image
    frame: np.ndarray | None = None    # to_world's rotation: local directions (+z the axis)
    projection: tuple[float, float] | None = None   # a projector's tan of half its field of view along x, y
    sampling_weight: float = 1.0       # Mitsuba's: relative to the other lights' (lights.choice)

    @property
    def varies(self) -> bool:
        """Whether its intensity depends on the direction beyond a spot's falloff (`profile`)."""
        return self.image is not None or self.projection is not None

    def profile(self, ref: Array3f) -> Array3f:
        """The factor on `intensity` towards the point `ref`. A spot's texture at uv = 1/2 + (x, y) / (2 z
        tan cutoff) of the local direction (x, y, z) (Mitsuba's spot.cpp, direction_to_uv). A projector's
        image at its perspective projection, uv = 1/2 - (x / tan_x, y / tan_y) / (2 z), zero outside [0, 1]^2
        or behind it, times pi / cos^3 of the angle to the axis: the image is the irradiance on the plane at
        distance 1 along the axis, so the intensity is E pi / cos^3 (Mitsuba's projector.cpp scales by pi
        its irradiance at z = 1, E / (z^2 cos) = E / (d^2 cos^3))."""
        m = self.frame
        d = ref - vec3(self.position)
        x, y, z = (dr.dot(vec3(m[:, k]), d) for k in range(3))
        if self.projection is None:
            t = float(np.tan(np.radians(self.spot[1])))
            u, v = 0.5 + 0.5 * x / (z * t), 0.5 + 0.5 * y / (z * t)
            inside = z > float(np.cos(np.radians(self.spot[1]))) * dr.norm(d)   # within the cone: |uv - 1/2| < 1/2
            factor = Float(1.0)
        else:
            tan_x, tan_y = self.projection
            u, v = 0.5 - 0.5 * x / (z * tan_x), 0.5 - 0.5 * y / (z * tan_y)
            inside = (z > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
            cos = z * dr.rsqrt(dr.squared_norm(d))
            factor = dr.pi / (cos * cos * cos)
        value = Array3f(factor)
        if self.image is not None:
            value *= self._texture.eval(UInt32(1), (u, v), inside)
        return dr.select(inside, value, Array3f(0.0))

    @property
    def _texture(self) -> TextureTables:
        if not hasattr(self, "_tables"):
            self._tables = TextureTables([self.image])
        return self._tables

    def cone(self) -> tuple[tuple[float, float, float], float, float, float, float]:
        """(axis, cos cutoff, cos beam width, cutoff in radians, 1 / transition width in radians); a point
        light's cone admits every direction at full intensity."""
        if self.spot is None:
            return (0.0, 0.0, 0.0), -2.0, -2.0, 0.0, 0.0
        axis, cutoff, beam = self.spot
        c, b = np.radians(cutoff), np.radians(beam)
        return tuple(float(x) for x in axis), float(np.cos(c)), float(np.cos(b)), float(c), float(1.0 / (c - b))

    def sample(self, pmf: float, spots: bool) -> LightSample:
        """Its position, chosen with probability pmf; the spot's axis rides in n, its cone in `cone` where
        the scene has spot lights."""
        axis, *cone = self.cone()
        return LightSample(vec3(self.position), vec3(axis), vec3(self.intensity), Float(pmf),
                           UInt32(POINT_LIGHT), tuple(Float(x) for x in cone) if spots else None)


def from_xml(ctx, props, node) -> PointLight:
    build = {"spot": _spot, "projector": _projector}.get(node.attrib.get("type"), _point)
    return build(ctx, props, node)


def _rotation(ctx, node, to_world: np.ndarray, what: str) -> np.ndarray:
    linear = to_world[:3, :3]
    if not np.allclose(linear.T @ linear, np.eye(3), atol=1e-5):
        raise ctx.error(node, f"a {what}'s to_world must be a rotation and a translation (no scale or shear)")
    return linear


def _projector(ctx, props, node) -> PointLight:
    """Mitsuba's `projector`: an image (`irradiance`, a bitmap or a colour) projected from to_world's origin
    along its +z through a perspective frustum of the image's aspect, `scale` times."""
    to_world = props.get("to_world", np.eye(4), ("transform",))
    image = props.colour("irradiance", 1.0, textured=True)
    scale = float(props.get("scale", 1.0, ("float", "integer")))
    fov, fov_axis = props.fov()
    weight = props.sampling_weight()
    props.finish()
    frame = _rotation(ctx, node, to_world, "projector")
    if not isinstance(image, (Bitmap, np.ndarray)):
        raise ctx.error(node, "a projector's irradiance must be a bitmap texture or a colour")
    intensity = rgb(np.full(3, scale)) if isinstance(image, Bitmap) else rgb(image * scale)
    if isinstance(image, np.ndarray) and np.any(image < 0) or scale < 0:
        raise ctx.error(node, "a projector's irradiance and scale must be non-negative")
    h, w = image.image.shape[:2] if isinstance(image, Bitmap) else (1, 1)
    from ..scene import Camera          # the frustum as the perspective sensor's (Mitsuba's parse_fov)
    tan_x, tan_y = Camera(to_world, fov, fov_axis, width=w, height=h).tan_half_fov()
    return PointLight(to_world[:3, 3].copy(), intensity, node.attrib.get("id", f"projector@{node.line}"),
                      image=image if isinstance(image, Bitmap) else None, frame=frame,
                      projection=(float(tan_x), float(tan_y)), sampling_weight=weight)


def _point(ctx, props, node) -> PointLight:
    """Mitsuba's `point` emitter: at `position`, or at the translation of `to_world`."""
    if props.has("position") and props.has("to_world"):
        raise ctx.error(node, "give either position or to_world, not both (as in Mitsuba)")
    position = props.get("position", None, ("point",))
    if position is None:
        position = props.get("to_world", np.eye(4), ("transform",))[:3, 3]
    intensity = props.colour("intensity", 1.0)
    weight = props.sampling_weight()
    props.finish()
    if np.any(intensity < 0):
        raise ctx.error(node, f"intensity must be non-negative, got {rgb(intensity)}")
    return PointLight(np.asarray(position, float), rgb(intensity), node.attrib.get("id", f"point@{node.line}"),
                      sampling_weight=weight)


def _spot(ctx, props, node) -> PointLight:
    """Mitsuba's `spot` emitter: at to_world's origin, along its +z, with a linear falloff in angle."""
    to_world = props.get("to_world", np.eye(4), ("transform",))
    intensity = props.colour("intensity", 1.0)
    cutoff = float(props.get("cutoff_angle", 20.0, ("float", "integer")))
    beam = float(props.get("beam_width", cutoff * 3.0 / 4.0, ("float", "integer")))
    texture = props.colour("texture", 1.0, textured=True) if props.has("texture") or _texture_child(props) else None
    weight = props.sampling_weight()
    props.finish()
    linear = _rotation(ctx, node, to_world, "spot light")
    if texture is not None and not isinstance(texture, Bitmap):
        raise ctx.error(node, "a spot light's texture must be a bitmap (spatially varying, as Mitsuba requires)")
    if not 0 < beam < cutoff < 180:
        raise ctx.error(node, f"need 0 < beam_width < cutoff_angle < 180 degrees, got {beam} and {cutoff}")
    if np.any(intensity < 0):
        raise ctx.error(node, f"intensity must be non-negative, got {rgb(intensity)}")
    axis = linear[:, 2] / np.linalg.norm(linear[:, 2])
    return PointLight(to_world[:3, 3].copy(), rgb(intensity), node.attrib.get("id", f"spot@{node.line}"),
                      spot=(axis, cutoff, beam), image=texture, frame=linear, sampling_weight=weight)


def _texture_child(props) -> bool:
    return any(o.attrib.get("name") == "texture" for o in props.objects)
