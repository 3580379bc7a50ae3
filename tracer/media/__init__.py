"""Participating media (Mitsuba 3's `homogeneous` and `heterogeneous`), their phase functions (`isotropic`,
`hg`) and volumes (`constvolume`, `gridvolume`): the host description the loader builds (medium.Medium) and
the scene's media as kernel code (kernel.MediaKernel), which the `volpath` integrator samples
(integrators.volpath)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..spectra import rgb
from . import phase as phases
from . import volumes
from .kernel import VACUUM, MediaKernel
from .medium import KINDS, PARAMETERS, Medium
from .phase import Phase
from .volumes import ConstVolume, GridVolume, VolumeFileError

__all__ = ["KINDS", "PARAMETERS", "VACUUM", "ConstVolume", "GridVolume", "MediaKernel", "Medium", "Phase",
           "medium_from_xml"]


def medium_from_xml(ctx, props, node, child_props) -> Medium:
    """A <medium>: `child_props(node)` gives the properties of a nested plugin (its type checked)."""
    phase_nodes = props.children("phase")
    if len(phase_nodes) > 1:
        raise ctx.error(phase_nodes[1], "only a single phase function can be specified per medium (as in Mitsuba)")
    phase = Phase()
    if phase_nodes:
        phase = ctx.built_once(phase_nodes[0], lambda n: phases.from_xml(ctx, child_props(n), n))
    sigma_t = _volume(ctx, props, "sigma_t", 1.0, child_props)
    albedo = _volume(ctx, props, "albedo", 0.75, child_props)
    scale = float(props.get("scale", 1.0, ("float", "integer")))
    emitters = bool(props.get("sample_emitters", True, ("boolean",)))
    spectral = bool(props.get("has_spectral_extinction", True, ("boolean",)))
    props.finish()
    if props.kind == "homogeneous" and not isinstance(sigma_t, ConstVolume):
        raise ctx.error(node, "a homogeneous medium's sigma_t must be constant (a number, rgb, spectrum or "
                              "constvolume); use a heterogeneous medium for a gridvolume")
    if scale < 0 or not np.isfinite(scale):
        raise ctx.error(node, f"scale must be a finite number >= 0, got {scale}")
    if sigma_t.max < 0 or (isinstance(sigma_t, ConstVolume) and min(sigma_t.value) < 0) or (
            isinstance(sigma_t, GridVolume) and sigma_t.data.min() < 0):
        raise ctx.error(node, "sigma_t must not be negative")
    return Medium(props.kind, sigma_t, albedo, scale, phase, emitters, spectral, node.attrib.get("id", ""))


def _volume(ctx, props, name: str, default: float, child_props):
    """A medium's quantity: a colour (<float>, <rgb>, <spectrum>: a constvolume) or a <volume>."""
    named = [o for o in props.objects if o.attrib.get("name") == name]
    if named:
        props.taken.add(id(named[0]))
        target = ctx.ids.get(named[0].attrib.get("id", ""), named[0]) if named[0].tag == "ref" else named[0]
        if target.tag != "volume":
            raise ctx.error(named[0], f"'{name}' given by a <{target.tag}>: unsupported; supported: <float>, <rgb>, "
                                      "<spectrum>, a constvolume or gridvolume <volume>")
        return ctx.built_once(target, lambda n: volume_from_xml(ctx, child_props(n), n))
    value = props.colour(name, default, unbounded=True)
    given = props.values.get(name)
    if given is not None and given.tag == "rgb" and not ((value >= 0) & (value <= 1)).all():
        raise ctx.error(given, f"an <rgb> {name} must lie in [0, 1], got ({', '.join(f'{x:g}' for x in value)}): "
                               "Mitsuba reads a medium's <rgb> as a reflectance; give a <float>, a <spectrum>, "
                               "a constvolume <volume> or a `scale`")
    return ConstVolume(rgb(value))


def volume_from_xml(ctx, props, node):
    to_world = props.get("to_world", np.eye(4), ("transform",))
    if props.kind == "constvolume":
        value = props.colour("value", 1.0, unbounded=True)
        props.finish()
        return ConstVolume(rgb(value), to_world)
    filename = props.get("filename", None, ("string",))
    filter_type = props.get("filter_type", "trilinear", ("string",))
    wrap = props.get("wrap_mode", "clamp", ("string",))
    use_bbox = props.get("use_grid_bbox", False, ("boolean",))
    props.get("raw", False, ("boolean",))      # spectral upsampling only: an RGB renderer reads the values as they are
    props.ignore("accel")                      # hardware texture filtering on GPUs: the same values
    props.finish()
    if filename is None:
        raise ctx.error(node, "a gridvolume needs a 'filename' (a .vol file); grids given in memory are unsupported")
    if filter_type not in volumes.FILTERS:
        raise ctx.error(props.values["filter_type"], f"invalid filter type '{filter_type}'; supported: "
                                                     "nearest, trilinear (as Mitsuba)")
    if wrap not in volumes.WRAPS:
        raise ctx.error(props.values["wrap_mode"], f"invalid wrap mode '{wrap}'; supported: repeat, mirror, clamp")
    path = ctx.resolve(filename)
    try:
        data, bbox = volumes.read_vol(Path(path))
    except (OSError, VolumeFileError) as e:
        raise ctx.error(props.values["filename"], str(e)) from None
    if use_bbox:
        to_world = to_world @ volumes.grid_bbox_transform(bbox)
    return GridVolume(data, to_world, filter_type, wrap)
