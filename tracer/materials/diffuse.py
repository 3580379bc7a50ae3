"""Mitsuba's `diffuse`, and `twosided` around it: the Lambertian BRDF."""
import numpy as np

from ..jit import Array3f
from ..sampling import INV_PI
from ..spectra import rgb
from .bsdf import BSDF
from .reading import check_unit_interval

PLUGINS = {"diffuse": ("reflectance",), "twosided": ("allow_transmission",)}


def diffuse_brdf(albedo: Array3f) -> Array3f:
    """Lambertian BRDF f = rho / pi (the f of eq. 10)."""
    return albedo * INV_PI


def from_xml(ctx, props, node) -> BSDF:
    if node.attrib.get("type") == "twosided":
        return _twosided(ctx, props, node)
    rho = props.colour("reflectance", 0.5, textured=True)
    props.finish()
    if not isinstance(rho, np.ndarray):
        return BSDF("diffuse", (0.0, 0.0, 0.0), texture=rho)
    check_unit_interval(ctx, node, "diffuse reflectance", rho)
    return BSDF("diffuse", rgb(rho))


def _twosided(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    if props.get("allow_transmission", False, ("boolean",)):
        raise ctx.error(props.values["allow_transmission"], "allow_transmission = true is not supported")
    props.finish()
    if len(inner) not in (1, 2):
        raise ctx.error(node, "twosided wraps one bsdf (or two)")
    bases = [ctx.bsdf(b) for b in inner]
    if any(b.kind != "diffuse" or b.twosided for b in bases):
        raise ctx.error(node, "twosided supports one-sided diffuse bsdfs only")
    if len(bases) == 2 and bases[0] != bases[1]:
        raise ctx.error(node, "twosided with different front and back bsdfs is unsupported")
    return BSDF("diffuse", bases[0].reflectance, twosided=True)
