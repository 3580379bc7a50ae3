"""Mitsuba's smooth `conductor`: a mirror weighted by its specular reflectance and the exact conductor Fresnel
term (materials.fresnel.fresnel_conductor) of a complex index, given as eta and k or by a material's name."""
import numpy as np

from ..ior import named_conductor
from ..spectra import rgb
from .bsdf import BSDF
from .reading import check_unit_interval

PLUGINS = {"conductor": ("material", "eta", "k", "specular_reflectance")}


def from_xml(ctx, props, node) -> BSDF:
    material = props.get("material", "none", ("string",))
    if props.has("eta") or material == "none":
        if material != "none":
            raise ctx.error(node, "give either eta and k or a material, not both (as in Mitsuba)")
        eta, k = props.colour("eta", 0.0, unbounded=True), props.colour("k", 1.0, unbounded=True)
    else:
        try:
            eta, k = (np.array(v) for v in named_conductor(material))
        except KeyError as e:
            raise ctx.error(props.values["material"], e.args[0]) from None
    spec = props.colour("specular_reflectance", 1.0)
    props.finish()
    check_unit_interval(ctx, node, "specular_reflectance", spec)
    return BSDF("conductor", rgb(spec), eta=rgb(eta), k=rgb(k))
