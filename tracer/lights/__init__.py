"""Lights, one module per kind: point and spot, directional, the environment (constant or a map). Area
lights are emitting shapes: each shape kind samples points on itself (tracer.shapes). tracer.geometry
chooses among a scene's lights uniformly."""
from .directional import DirectionalLight
from .envmap import EnvironmentMap
from .point import PointLight
from .sample import DIRECTIONAL_LIGHT, POINT_LIGHT, LightSample, select_sample

__all__ = ["DIRECTIONAL_LIGHT", "POINT_LIGHT", "DirectionalLight", "EnvironmentMap", "LightSample", "PointLight",
           "select_sample"]
