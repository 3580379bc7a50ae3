"""Variants of a scene file: its XML text changed, written beside copies of the meshes it names, so
that Mitsuba and the tracer read the same variant."""
from __future__ import annotations

import shutil
from pathlib import Path

from .scenefile import referenced_files

BOX_FILTER = '<rfilter type="box"/>'


def write_variant(scene_file: Path, text: str, folder: Path, name: str) -> Path:
    """Writes `text` as folder/name.xml and copies the meshes of `scene_file` to the same relative paths."""
    scene_file = Path(scene_file)
    for mesh in referenced_files(scene_file)[1:]:
        target = folder / mesh.relative_to(scene_file.parent)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mesh, target)
    out = folder / f"{name}.xml"
    out.write_text(text)
    return out


def with_filter(scene_file: Path, rfilter_xml: str, folder: Path, name: str) -> Path:
    """The scene with its box filter replaced by `rfilter_xml` ('' leaves Mitsuba's default, Gaussian)."""
    text = Path(scene_file).read_text()
    if BOX_FILTER not in text:
        raise ValueError(f"{scene_file}: no {BOX_FILTER} to replace")
    return write_variant(scene_file, text.replace(BOX_FILTER, rfilter_xml), folder, name)
