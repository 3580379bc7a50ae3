"""Shapes, one module per kind: the host description the loader builds (its `from_xml`, for the XML plugins
in its PLUGINS), and the ShapeSet that gives the scene's kernels its ray test, normals and area sampling.

A scene's primitives are numbered kind after kind in the order of SETS, planar kinds first (tracer.geometry
keeps their hit points inside by their frames). A new kind is a module with a host dataclass, `from_xml`,
PLUGINS and a ShapeSet subclass (its `kind`), listed here.
"""
from . import cube, cylinder, mesh, rectangle, sphere
from .base import ShapeArgs, ShapeSet
from .cylinder import Cylinder, CylinderSet
from .mesh import BVH_THRESHOLD, Mesh, MeshSet
from .rectangle import Rectangle, RectangleSet
from .sphere import Sphere, SphereSet

SETS: tuple[type[ShapeSet], ...] = (RectangleSet, MeshSet, SphereSet, CylinderSet)
PLUGINS = {name: module for module in (rectangle, sphere, cylinder, mesh, cube) for name in module.PLUGINS}


def in_primitive_order(shapes: list) -> list:
    """The shapes grouped kind by kind in the order of SETS, each kind's in the order given."""
    return [s for cls in SETS for s in shapes if isinstance(s, cls.kind)]


__all__ = ["BVH_THRESHOLD", "PLUGINS", "SETS", "Cylinder", "CylinderSet", "Mesh", "MeshSet", "Rectangle",
           "RectangleSet", "ShapeArgs", "ShapeSet", "Sphere", "SphereSet", "in_primitive_order"]
