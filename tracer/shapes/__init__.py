"""Shapes, one module per kind: the host description the loader builds, and the ShapeSet that gives the
scene's kernels its ray test, normals and area sampling. A scene's primitives are numbered kind after kind
in the order of KINDS (planar kinds first: tracer.geometry keeps their hit points inside by their frames)."""
from .base import ShapeSet
from .cylinder import Cylinder, CylinderSet
from .mesh import BVH_THRESHOLD, Mesh, MeshSet
from .rectangle import Rectangle, RectangleSet
from .sphere import Sphere, SphereSet

KINDS = ((Rectangle, RectangleSet), (Mesh, MeshSet), (Sphere, SphereSet), (Cylinder, CylinderSet))

__all__ = ["BVH_THRESHOLD", "KINDS", "Cylinder", "CylinderSet", "Mesh", "MeshSet", "Rectangle", "RectangleSet",
           "ShapeSet", "Sphere", "SphereSet"]
