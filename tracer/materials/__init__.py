"""Materials (Mitsuba's BSDFs), one module per kind behind one interface (materials.bsdf): the host description
the loader builds (BSDF), the per-material tables the kernels gather from (tables.MaterialTables) and the BSDF
at a surface point for any kind (dispatch.SurfaceBSDF)."""
from . import blendbsdf, bumpmap, conductor, dielectric, diffuse, mask, normalmap, plastic, textures, twosided
from .bsdf import BSDF
from .dispatch import KIND_CODE, KINDS, SurfaceBSDF
from .tables import MaterialTables
from .textures import Bitmap, Checkerboard

DIFFUSE, CONDUCTOR, DIELECTRIC, PLASTIC = (KIND_CODE[k] for k in ("diffuse", "conductor", "dielectric", "plastic"))

# XML plugin name -> the module whose from_xml reads it (its PLUGINS: the parameters Mitsuba reads)
PLUGINS = {name: module for module in (*KINDS, twosided, mask, blendbsdf, normalmap, bumpmap) for name in module.PLUGINS}

__all__ = ["BSDF", "CONDUCTOR", "DIELECTRIC", "DIFFUSE", "KIND_CODE", "KINDS", "PLASTIC", "Bitmap", "Checkerboard",
           "MaterialTables", "PLUGINS", "SurfaceBSDF", "textures"]
