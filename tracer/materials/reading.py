"""What the material modules' `from_xml` share: indices of refraction by value or name, reflectance bounds."""
import numpy as np

from ..ior import named_conductor, named_ior
from ..spectra import rgb
from .textures import Checkerboard, Constant


def read_ior(ctx, props, name: str, default: str) -> float:
    """An index of refraction given as a number or by name (Mitsuba's table, tracer.ior)."""
    value = props.get(name, default, ("float", "integer", "string"))
    if isinstance(value, str):
        try:
            return named_ior(value)
        except KeyError as e:
            raise ctx.error(props.values.get(name, props.node), e.args[0]) from None
    return float(value)


def check_unit_interval(ctx, node, name: str, value) -> None:
    """Refuses a reflectance outside [0, 1]: a colour, or a checkerboard's or rawconstant's values (a bitmap's
    are not checked)."""
    if isinstance(value, (Checkerboard, Constant)):
        lo, hi = value.bounds()
        if lo < 0 or hi > 1:
            raise ctx.error(node, f"{name}: the texture's values must lie in [0, 1], got {lo:g} to {hi:g}")
    elif isinstance(value, np.ndarray) and (np.any(value < 0) or np.any(value > 1)):
        raise ctx.error(node, f"{name} must lie in [0, 1], got {rgb(value)}")


def check_fraction(ctx, props, node, name: str, value: float) -> None:
    """Refuses a float weight (mask's opacity, blendbsdf's weight) outside [0, 1], at its own line."""
    if not 0.0 <= value <= 1.0:
        raise ctx.error(props.values.get(name, node), f"{name} must lie in [0, 1], got {value}")


DISTRIBUTIONS = ("beckmann", "ggx")


def read_microfacet(ctx, props, node, anisotropic: bool = True, textured: bool = True) -> dict:
    """A microfacet distribution's parameters as Mitsuba reads them: `distribution` (beckmann by default),
    `alpha` (0.1) or both `alpha_u` and `alpha_v`, `sample_visible` (true). Refuses what Mitsuba refuses
    (only one of alpha_u / alpha_v, alpha with them, another distribution, negative roughness) and
    alpha_u != alpha_v where not `anisotropic` (roughplastic). alpha_u runs along the shading frame's first
    tangent, the surface's dp/du (materials.dispatch.shading_tangents). Where `textured` (roughconductor,
    roughdielectric), a roughness may be a texture (slots alpha_u and alpha_v, one and the same texture for
    `alpha`): then the BSDF's `textures` hold it."""
    distribution = props.get("distribution", "beckmann", ("string",)).lower()
    if distribution not in DISTRIBUTIONS:
        raise ctx.error(props.values["distribution"], f"invalid distribution '{distribution}': must be "
                                                      "'beckmann' or 'ggx' (as in Mitsuba)")

    def given(name: str) -> bool:
        return props.has(name) or any(o.attrib.get("name") == name for o in props.objects)

    named = [name for name in ("alpha_u", "alpha_v") if given(name)]
    if named and given("alpha"):
        raise ctx.error(node, "give either alpha or alpha_u and alpha_v, not both (as in Mitsuba)")
    if len(named) == 1:
        raise ctx.error(node, "both alpha_u and alpha_v must be given (as in Mitsuba)")
    if named:
        (alpha_u, tex_u), (alpha_v, tex_v) = (props.scalar(n, 0.1, textured) for n in ("alpha_u", "alpha_v"))
    else:
        alpha_u, tex_u = props.scalar("alpha", 0.1, textured)
        alpha_v, tex_v = alpha_u, tex_u
    if min(alpha_u, alpha_v) < 0:
        raise ctx.error(node, f"roughness must not be negative, got alpha_u = {alpha_u}, alpha_v = {alpha_v}")
    if alpha_u != alpha_v and not anisotropic:
        raise ctx.error(node, f"anisotropic roughness (alpha_u = {alpha_u}, alpha_v = {alpha_v}) is not "
                              f"supported by '{props.kind}' (nor by Mitsuba)")
    visible = props.get("sample_visible", True, ("boolean",))
    textures = tuple((slot, t) for slot, t in (("alpha_u", tex_u), ("alpha_v", tex_v)) if t is not None)
    return dict(distribution=distribution, alpha_u=alpha_u, alpha_v=alpha_v, sample_visible=bool(visible),
                textures=textures)


def read_complex_ior(ctx, props, node) -> tuple[np.ndarray, np.ndarray]:
    """A conductor's eta and k: given (unbounded colours; eta 0, k 1 by default) or by `material` name
    (tracer.ior), not both, as Mitsuba reads them."""
    material = props.get("material", "none", ("string",))
    if props.has("eta") or material == "none":
        if material != "none":
            raise ctx.error(node, "give either eta and k or a material, not both (as in Mitsuba)")
        return props.colour("eta", 0.0, unbounded=True), props.colour("k", 1.0, unbounded=True)
    try:
        return tuple(np.array(v) for v in named_conductor(material))
    except KeyError as e:
        raise ctx.error(props.values["material"], e.args[0]) from None
