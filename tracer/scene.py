"""The scene description both renderers read: what the XML loader produces and the kernels consume.

The camera and the lists of shapes (tracer.shapes), lights (tracer.lights) and their materials
(tracer.materials), as plain host-side data (NumPy).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .film import Film, ReconstructionFilter
from .integrators.ptracer import NOTE as PTRACER_NOTE
from .lights import DELTA_KINDS, ConstantEnvironment, DirectionalLight, EnvironmentMap, PointLight
from .materials import BSDF
from .meshes import bounding_box
from .shapes import Cylinder, Mesh, Rectangle, Sphere, in_primitive_order


# Mitsuba's polarization-aware BSDFs, as its unpolarized variants render them: what differs from a polarized render
UNPOLARIZED = {"polarizer": "half the transmittance passes, whatever theta (the polarizer's axis)",
               "pplastic": "unpolarized Fresnel factors, as Mitsuba's own RGB variants"}


class SceneError(ValueError):
    """A scene that cannot be rendered; the message is one line naming file, line and element."""


@dataclass
class Camera:
    """Mitsuba's `perspective` (or `thinlens`, or `orthographic`) sensor with an `hdrfilm` and its
    reconstruction filter."""

    to_world: np.ndarray
    fov: float = 90.0
    fov_axis: str = "x"
    near_clip: float = 1e-2
    far_clip: float = 1e4
    width: int = 768
    height: int = 576
    rfilter: ReconstructionFilter = ReconstructionFilter("gaussian")   # Mitsuba's default
    projection: str = "perspective"      # or "orthographic": Mitsuba's sensor of that name (no fov)
    aperture_radius: float = 0.0         # a `thinlens` sensor's lens (0: a pinhole)
    focus_distance: float = 0.0          # the distance along the view axis that it brings into focus
    # hdrfilm's crop window: the image (width x height) is the part of a film_width x film_height film whose
    # top-left pixel is (crop_x, crop_y); film_width 0: no crop, the image is the film
    film_width: int = 0
    film_height: int = 0
    crop_x: int = 0
    crop_y: int = 0
    sample_border: bool = False          # hdrfilm's: camera rays also start in the filter's border around the image

    @property
    def film_size(self) -> tuple[int, int]:
        """The whole film, in pixels: the image's size where there is no crop."""
        return (self.film_width, self.film_height) if self.film_width else (self.width, self.height)

    @property
    def cropped(self) -> bool:
        return self.film_size != (self.width, self.height)

    @property
    def border(self) -> int:
        """Pixels sampled beyond each edge of the image: the filter's reach with sample_border, else 0
        (Mitsuba's border_size, tracer.film.Film.border_of)."""
        return Film.border_of(self.rfilter) if self.sample_border else 0

    @property
    def sampled_size(self) -> tuple[int, int]:
        """The pixels camera rays start in, each `spp` times: the image and its sampled border."""
        return self.width + 2 * self.border, self.height + 2 * self.border

    def tan_half_fov(self) -> tuple[float, float]:
        """tan of half the field of view along image x and y, from `fov` and `fov_axis` (over the whole film)."""
        width, height = self.film_size
        aspect = width / height
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
    shapes: list = field(default_factory=list)   # of the kinds in tracer.shapes, in the file's order
    spp: int = 4
    seed: int = 0
    max_depth: int = -1
    rr_depth: int = 5
    integrator: str = "path"                      # the scene's integrator, e.g. "moment around path"
    sampler: str = "independent"                  # the scene's sampler; the tracer's samples are independent
    instances: int = 0                            # Mitsuba `instance`s (their meshes in `groups`, the rest expanded)
    groups: list = field(default_factory=list)    # of tracer.shapes.instance.ShapeGroup: instanced meshes
    shading_samples: tuple[int, int] = (1, 1)     # `direct`'s emitter and BSDF samples (integrators.path.Strategies)
    spectral_mis: bool = False                    # volpathmis's balance heuristic over the channels' distance sampling
    lights: list = field(default_factory=list)    # of the kinds in tracer.lights (area lights: emitting shapes)
    path: Path | None = None
    media: list = field(default_factory=list)        # of tracer.media.Medium, in the order of their codes 1, 2, ...
    shape_media: dict = field(default_factory=dict)  # a shape -> its (interior, exterior) medium codes (0: none)
    camera_medium: int = 0                           # the code of the medium the camera sits in
    # the integrator's hide_emitters, as Mitsuba 3.9.1's: None (shown); "pass": camera rays pass through emitting
    # shapes and see no environment (path, direct); "dark": emission reaching the camera directly is left out,
    # the emitting shapes still reflect and occlude (ptracer)
    hide_emitters: str | None = None

    @property
    def volumetric(self) -> bool:
        """Whether the scene's integrator is `volpath` or `volpathmis` (its expected image: volpath's), which
        render its media."""
        return self.integrator.split()[-1] in ("volpath", "volpathmis")

    def of_kind(self, kind: type) -> list:
        return [s for s in self.shapes if isinstance(s, kind)]

    @property
    def rectangles(self) -> list[Rectangle]:
        return self.of_kind(Rectangle)

    @property
    def meshes(self) -> list[Mesh]:
        return self.of_kind(Mesh)

    @property
    def spheres(self) -> list[Sphere]:
        return self.of_kind(Sphere)

    @property
    def cylinders(self) -> list[Cylinder]:
        return self.of_kind(Cylinder)

    @property
    def point_lights(self) -> list[PointLight]:
        return [x for x in self.lights if isinstance(x, PointLight)]

    @property
    def directional_lights(self) -> list[DirectionalLight]:
        return [x for x in self.lights if isinstance(x, DirectionalLight)]

    @property
    def delta_lights(self) -> list:
        """Point, spot and directional lights, kind by kind in the order of tracer.lights.DELTA_KINDS."""
        return [x for kind in DELTA_KINDS for x in self.lights if isinstance(x, kind)]

    @property
    def environment(self) -> tuple[float, float, float] | None:
        """A `constant` emitter's radiance, arriving from all directions."""
        return next((x.radiance for x in self.lights if isinstance(x, ConstantEnvironment)), None)

    @property
    def envmap(self) -> EnvironmentMap | None:
        return next((x for x in self.lights if isinstance(x, EnvironmentMap)), None)

    @property
    def has_environment(self) -> bool:
        """Whether light arrives from all directions at infinity (a `constant` or an `envmap` emitter)."""
        return self.environment is not None or self.envmap is not None

    @property
    def emitters(self) -> list:
        """The emitting shapes (area lights), in primitive order."""
        return [s for s in in_primitive_order(self.shapes) if s.radiance is not None]

    def notes(self) -> list[str]:
        """How the tracer renders what the scene asks for by another method than Mitsuba, each giving the
        same expected image (`tracer info` prints them)."""
        out = []
        if self.integrator.startswith("moment"):
            out.append("renders the nested integrator's image; a moment's second-moment images are not written")
        if "aov around" in self.integrator:
            out.append("renders the aov integrator's first nested integrator's image; its AOV channels (and "
                       "further nested integrators' images) are not written")
        if self.integrator.endswith("direct"):
            out.append(f"direct: the path estimator at max_depth 2, one sample of each strategy used per pixel "
                       f"sample, weighted as Mitsuba weights {self.shading_samples[0]} emitter and "
                       f"{self.shading_samples[1]} BSDF samples (the same expected image, other noise)")
        if self.integrator.endswith("volpathmis"):
            out.append("volpathmis: the tracer's volpath with spectral MIS (the channels' distance sampling weighted "
                       "by the one-sample balance heuristic, as Mitsuba's use_spectral_mis); emitter and BSDF/phase "
                       "sampling weighted by the power heuristic as in volpath (Mitsuba's volpathmis: the balance "
                       "heuristic), which changes the noise, not the expected image"
                       if self.spectral_mis else
                       "volpathmis with use_spectral_mis = false: rendered with the tracer's volpath (the same "
                       "expected image, other noise)")
        if self.integrator.endswith("ptracer"):
            out.append(PTRACER_NOTE)
        if self.hide_emitters == "pass":
            out.append("hide_emitters: camera rays pass through emitting shapes and see no environment (as Mitsuba's "
                       "path and direct)")
        if self.hide_emitters == "dark":
            out.append("hide_emitters: no emission reaches the camera directly; emitting shapes still reflect and "
                       "occlude (as Mitsuba's ptracer)")
        if self.instances:
            instanced = sum(len(g.to_world) for g in self.groups if g.meshes)
            out.append(f"{self.instances} instance(s) of shapegroups: their meshes instanced ({instanced} instance(s) "
                       f"of {sum(len(g.meshes) for g in self.groups)} mesh(es) held once, in a two-level BVH), "
                       "meshes with mesh_attribute textures and any other shapes of theirs expanded into copies per instance (the "
                       "same image as Mitsuba's instancing)")
        kinds = {b.kind for b in self.bsdfs}
        for kind in sorted(kinds & set(UNPOLARIZED)):
            out.append(f"{kind}: rendered as Mitsuba's RGB (unpolarized) variants render it; {UNPOLARIZED[kind]}")
        if self.sampler != "independent":
            out.append(f"sampler '{self.sampler}': rendered with the independent sampler at its {self.spp} spp "
                       "(the same expected image, other noise)")
        return out

    def estimator_refusals(self, estimator: str) -> list[str]:
        """What the named estimator cannot render correctly in this scene, one line each (empty: nothing)."""
        out = []
        if estimator == "report" and self.hide_emitters:
            out.append(f"{self.path}: the report estimator does not hide emitters (the integrator's hide_emitters); "
                       "use --estimator path")
        if estimator == "report" and self.volumetric:
            what = (f"participating media ({', '.join(sorted({m.kind for m in self.media}))})" if self.media else
                    "the volpath integrator (whose shadow rays cross null surfaces)")
            out.append(f"{self.path}: the report estimator does not render {what}; use --estimator path")
        if estimator == "report" and self.has_environment:
            plugin = "constant" if self.environment is not None else "envmap"
            out.append(f"{self.path}: the report estimator does not render the '{plugin}' emitter (an environment); "
                       "use --estimator path")
        if estimator == "report" and any(b.kind == "plastic" for b in self.bsdfs):
            out.append(f"{self.path}: the report estimator does not render the 'plastic' bsdf; use --estimator path")
        split = ("dielectric", "thindielectric")
        for b in self.bsdfs:
            kinds = [b.kind] + ([b.blend[1].kind] if b.blend is not None else [])
            wrapper = "blendbsdf" if b.blend is not None else "mask" if b.masked else None
            if estimator == "report" and wrapper and any(k in split for k in kinds):
                out.append(f"{self.path}: the report estimator does not render a '{wrapper}' of "
                           f"'{next(k for k in kinds if k in split)}'; use --estimator path")
                break
        if estimator == "report" and 0 in self.shading_samples:
            out.append(f"{self.path}: the report estimator samples both lights and BSDFs; the scene's direct "
                       f"integrator draws {self.shading_samples[0]} emitter and {self.shading_samples[1]} BSDF "
                       "samples; use --estimator path")
        if estimator == "report" and any(b.every_texture() for b in self.bsdfs):
            out.append(f"{self.path}: the report estimator does not render textures (checkerboard, bitmap, "
                       "rawconstant, mesh_attribute, normalmap); use --estimator path")
        return out

    @property
    def bsdfs(self) -> list[BSDF]:
        seen: list[BSDF] = []
        for s in in_primitive_order(self.shapes) + [m for g in self.groups for m in g.meshes]:
            if s.bsdf not in seen:
                seen.append(s.bsdf)
        return seen

    @property
    def triangle_count(self) -> int:
        """The triangles of the meshes that are not instanced."""
        return sum(len(m.faces) for m in self.meshes)

    @property
    def instanced_triangles(self) -> tuple[int, int]:
        """(the triangles held by the shapegroups, those their instances draw)."""
        return (sum(g.triangles for g in self.groups),
                sum(g.triangles * len(g.to_world) for g in self.groups))

    def extent(self) -> float:
        """Diagonal of the bounding box of all geometry (the scene's length scale)."""
        pts = [np.atleast_2d(p) for s in self.shapes + self.groups for p in s.extent_points()]
        if not pts:
            return 1.0
        lo, hi = bounding_box(pts)
        return float(np.linalg.norm(hi - lo)) or 1.0
