"""The scene description both renderers read: what the XML loader produces and the kernels consume.

Plain host-side data (NumPy); nothing here touches Dr.Jit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .film import ReconstructionFilter

from . import transform


class SceneError(ValueError):
    """A scene that cannot be rendered; the message is one line naming file, line and element."""


@dataclass(frozen=True)
class Checkerboard:
    """Mitsuba's `checkerboard` texture: with (u', v') = to_uv (u, v), color0 where the fractional parts of u'
    and v' are both above 1/2 or both not, color1 elsewhere."""

    color0: tuple[float, float, float] = (0.4, 0.4, 0.4)
    color1: tuple[float, float, float] = (0.2, 0.2, 0.2)
    to_uv: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True, eq=False)
class Bitmap:
    """Mitsuba's `bitmap` texture (tracer/bitmap.py): a linear RGB image looked up at to_uv (u, v)."""

    image: np.ndarray                      # (H, W, 3) float32
    to_uv: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    bilinear: bool = True
    repeat: bool = True                    # else clamp


@dataclass(frozen=True)
class BSDF:
    """`diffuse` (Lambertian, one-sided unless `twosided`), `conductor` (smooth: `reflectance` times the exact
    Fresnel reflectance of the complex index eta + i k; eta 0, k 1 is a perfect mirror), `dielectric`, or
    `plastic` (Mitsuba's smooth plastic: a dielectric interface over a diffuse base of `reflectance`)."""

    kind: str
    reflectance: tuple[float, float, float] = (0.5, 0.5, 0.5)
    twosided: bool = False
    int_ior: float = 1.5046
    ext_ior: float = 1.000277
    eta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    k: tuple[float, float, float] = (1.0, 1.0, 1.0)
    texture: Checkerboard | Bitmap | None = None   # a diffuse reflectance given by a texture
    specular_reflectance: tuple[float, float, float] = (1.0, 1.0, 1.0)   # plastic's specular layer
    nonlinear: bool = False                                              # plastic's internal scattering model

    @property
    def perfect_mirror(self) -> bool:
        """A conductor that reflects everything at every angle (Fresnel reflectance 1, reflectance 1)."""
        return self.eta == (0.0, 0.0, 0.0) and self.k == (1.0, 1.0, 1.0) and self.reflectance == (1.0, 1.0, 1.0)



@dataclass(eq=False)
class Rectangle:
    """Mitsuba's `rectangle`: [-1,1]^2 in the local xy-plane, normal +z, placed by `to_world`; with `disk`,
    Mitsuba's `disk`: the unit disk in that plane."""

    to_world: np.ndarray
    bsdf: BSDF
    radiance: tuple[float, float, float] | None = None
    name: str = ""
    disk: bool = False

    @property
    def center(self) -> np.ndarray:
        return self.to_world[:3, 3].copy()

    @property
    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Half-edge vectors: the images of local +x and +y."""
        return self.to_world[:3, 0].copy(), self.to_world[:3, 1].copy()

    @property
    def dual_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the inverse transform: dot(p - center, du) is the local x coordinate of p."""
        inv = np.linalg.inv(self.to_world[:3, :3])
        return inv[0].copy(), inv[1].copy()

    @property
    def normal(self) -> np.ndarray:
        return transform.apply_normal(self.to_world, [0.0, 0.0, 1.0])[0]

    @property
    def area(self) -> float:
        e1, e2 = self.edges
        return (np.pi if self.disk else 4.0) * float(np.linalg.norm(np.cross(e1, e2)))


@dataclass(eq=False)
class Sphere:
    center: np.ndarray
    radius: float
    bsdf: BSDF
    name: str = ""
    radiance: tuple[float, float, float] | None = None   # an area light on it emits outward

    @property
    def area(self) -> float:
        return 4.0 * np.pi * self.radius * self.radius


@dataclass(eq=False)
class Cylinder:
    """Mitsuba's `cylinder`: the open tube x^2 + y^2 = 1, 0 <= z <= 1 of the local frame `to_world` (which
    already holds p0, p1 and the radius; it scales x and y alike), normals outward unless `flipped`."""

    to_world: np.ndarray
    bsdf: BSDF
    flipped: bool = False
    name: str = ""
    radiance: None = None

    @property
    def corners(self) -> np.ndarray:
        """The corners of its local bounding box [-1, 1]^2 x [0, 1], in world space."""
        local = np.array([[x, y, z, 1.0] for x in (-1, 1) for y in (-1, 1) for z in (0, 1)])
        return (local @ self.to_world.T)[:, :3]


@dataclass(eq=False)
class Mesh:
    """A triangle mesh in world space; `normals` are per-vertex shading normals, None for face normals."""

    vertices: np.ndarray
    faces: np.ndarray
    bsdf: BSDF
    normals: np.ndarray | None = None
    radiance: tuple[float, float, float] | None = None
    name: str = ""
    uvs: np.ndarray | None = None        # per-vertex texture coordinates; None: a triangle's (b1, b2)

    @property
    def triangle_areas(self) -> np.ndarray:
        v = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


@dataclass(eq=False)
class PointLight:
    """Mitsuba's `point` emitter: `intensity` (radiant intensity) from `position` in every direction; with
    `spot` = (axis, cutoff_angle, beam_width) in degrees, Mitsuba's `spot`: full intensity within beam_width
    of the axis, falling linearly in angle to 0 at cutoff_angle."""

    position: np.ndarray
    intensity: tuple[float, float, float]
    name: str = ""
    spot: tuple[np.ndarray, float, float] | None = None

    def cone(self) -> tuple[tuple[float, float, float], float, float, float, float]:
        """(axis, cos cutoff, cos beam width, cutoff in radians, 1 / transition width in radians); a point
        light's cone admits every direction at full intensity."""
        if self.spot is None:
            return (0.0, 0.0, 0.0), -2.0, -2.0, 0.0, 0.0
        axis, cutoff, beam = self.spot
        c, b = np.radians(cutoff), np.radians(beam)
        return tuple(float(x) for x in axis), float(np.cos(c)), float(np.cos(b)), float(c), float(1.0 / (c - b))


@dataclass(eq=False)
class DirectionalLight:
    """Mitsuba's `directional` emitter: `irradiance` arriving along the unit vector `direction` (the way the
    light travels) from infinitely far away."""

    direction: np.ndarray
    irradiance: tuple[float, float, float]
    name: str = ""


@dataclass(eq=False)
class EnvironmentMap:
    """Mitsuba's `envmap`: a latitude-longitude image of radiance (already times `scale`) around the scene,
    turned by `to_world` (tracer/envmap.py states the mapping)."""

    image: np.ndarray          # (H, W, 3) float32 linear RGB
    to_world: np.ndarray
    name: str = ""


@dataclass
class Camera:
    """Mitsuba's `perspective` sensor with an `hdrfilm` and its reconstruction filter."""

    to_world: np.ndarray
    fov: float = 90.0
    fov_axis: str = "x"
    near_clip: float = 1e-2
    far_clip: float = 1e4
    width: int = 768
    height: int = 576
    rfilter: ReconstructionFilter = ReconstructionFilter("gaussian")   # Mitsuba's default

    def tan_half_fov(self) -> tuple[float, float]:
        """tan of half the field of view along image x and y, from `fov` and `fov_axis`."""
        aspect = self.width / self.height
        t = float(np.tan(np.radians(self.fov) / 2))
        axis = self.fov_axis
        if axis == "smaller":
            axis = "x" if aspect <= 1 else "y"
        elif axis == "larger":
            axis = "x" if aspect > 1 else "y"
        if axis == "x":
            return t, t / aspect
        if axis == "y":
            return t * aspect, t
        diag = t / np.hypot(aspect, 1.0)  # "diagonal"
        return diag * aspect, diag


@dataclass
class Scene:
    camera: Camera
    rectangles: list[Rectangle] = field(default_factory=list)
    meshes: list[Mesh] = field(default_factory=list)
    spheres: list[Sphere] = field(default_factory=list)
    cylinders: list[Cylinder] = field(default_factory=list)
    spp: int = 4
    seed: int = 0
    max_depth: int = -1
    rr_depth: int = 5
    environment: tuple[float, float, float] | None = None   # a `constant` emitter's radiance, from all directions
    envmap: EnvironmentMap | None = None                     # or an `envmap` emitter
    point_lights: list[PointLight] = field(default_factory=list)
    directional_lights: list[DirectionalLight] = field(default_factory=list)
    path: Path | None = None

    @property
    def emitters(self) -> list[Rectangle | Mesh | Sphere]:
        return [s for s in (*self.rectangles, *self.meshes, *self.spheres) if s.radiance is not None]

    def estimator_refusals(self, estimator: str) -> list[str]:
        """What the named estimator cannot render correctly in this scene, one line each (empty: nothing)."""
        out = []
        if estimator == "report" and (self.environment is not None or self.envmap is not None):
            plugin = "constant" if self.environment is not None else "envmap"
            out.append(f"{self.path}: the report estimator does not render the '{plugin}' emitter (an environment); "
                       "use --estimator path")
        if estimator == "report" and any(b.kind == "plastic" for b in self.bsdfs):
            out.append(f"{self.path}: the report estimator does not render the 'plastic' bsdf; use --estimator path")
        if estimator == "report" and any(b.texture is not None for b in self.bsdfs):
            out.append(f"{self.path}: the report estimator does not render textures (checkerboard, bitmap); "
                       "use --estimator path")
        return out

    @property
    def bsdfs(self) -> list[BSDF]:
        seen: list[BSDF] = []
        for s in (*self.rectangles, *self.meshes, *self.spheres, *self.cylinders):
            if s.bsdf not in seen:
                seen.append(s.bsdf)
        return seen

    @property
    def triangle_count(self) -> int:
        return sum(len(m.faces) for m in self.meshes)

    def extent(self) -> float:
        """Diagonal of the bounding box of all geometry (the scene's length scale)."""
        pts = [r.center + s * e for r in self.rectangles for e in r.edges for s in (-1, 1)]
        pts += [m.vertices for m in self.meshes]
        pts += [np.stack([s.center - s.radius, s.center + s.radius]) for s in self.spheres]
        pts += [c.corners for c in self.cylinders]
        if not pts:
            return 1.0
        allp = np.vstack([np.atleast_2d(p) for p in pts])
        return float(np.linalg.norm(allp.max(0) - allp.min(0))) or 1.0
