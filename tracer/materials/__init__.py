"""Materials (Mitsuba's BSDFs), one module per kind: the host description the loader builds (BSDF), the
per-material tables the kernels gather from (tables.MaterialTables) and each kind's scattering terms."""
from . import conductor, dielectric, diffuse, plastic, textures
from .bsdf import BSDF, CONDUCTOR, DIELECTRIC, DIFFUSE, KIND_CODE, PLASTIC
from .tables import MaterialTables
from .textures import Bitmap, Checkerboard

# XML plugin name -> the module whose from_xml reads it (its PLUGINS: the parameters Mitsuba reads)
PLUGINS = {name: module for module in (diffuse, conductor, dielectric, plastic) for name in module.PLUGINS}

__all__ = ["BSDF", "CONDUCTOR", "DIELECTRIC", "DIFFUSE", "KIND_CODE", "PLASTIC", "Bitmap", "Checkerboard",
           "MaterialTables", "PLUGINS", "textures"]
