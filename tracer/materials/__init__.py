"""Materials (Mitsuba's BSDFs), one module per kind: the host description the loader builds (BSDF), the
per-material tables the kernels gather from (tables.MaterialTables) and each kind's scattering terms."""
from .bsdf import BSDF, CONDUCTOR, DIELECTRIC, DIFFUSE, KIND_CODE, PLASTIC
from .tables import MaterialTables
from .textures import Bitmap, Checkerboard

__all__ = ["BSDF", "CONDUCTOR", "DIELECTRIC", "DIFFUSE", "KIND_CODE", "PLASTIC", "Bitmap", "Checkerboard",
           "MaterialTables"]
