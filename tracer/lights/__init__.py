"""Lights, one module per kind: point and spot, directional, the environment (constant or a map). Area
lights are emitting shapes: each shape kind samples points on itself (tracer.shapes). tracer.geometry
chooses among a scene's lights uniformly."""
from . import constant, directional, envmap, point
from .constant import ConstantEnvironment
from .directional import DirectionalLight
from .envmap import EnvironmentMap
from .point import PointLight
from .sample import DIRECTIONAL_LIGHT, POINT_LIGHT, LightSample, select_sample

# delta lights, in the order the kernel's light choice numbers them: each kind's `sample(n_lights, spots)`
# returns a LightSample whose prim is POINT_LIGHT (a position) or DIRECTIONAL_LIGHT (at infinity)
DELTA_KINDS = (PointLight, DirectionalLight)

# XML plugin name -> its module (PLUGINS: the parameters Mitsuba reads; ENVIRONMENT: at most one per scene;
# from_xml: the light); area emitters are read with their shapes
PLUGINS = {name: module for module in (constant, envmap, point, directional) for name in module.PLUGINS}

__all__ = ["DELTA_KINDS", "DIRECTIONAL_LIGHT", "PLUGINS", "POINT_LIGHT", "ConstantEnvironment", "DirectionalLight", "EnvironmentMap", "LightSample", "PointLight",
           "select_sample"]
