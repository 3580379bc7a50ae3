"""A stand-in for "your own renderer", for `validate check --renderer`: renders a scene with Mitsuba 3's Python
API and writes an EXR, optionally scaling the image (a deliberately wrong renderer).

    python examples/mitsuba_renderer.py SCENE.xml -o OUT.exr --spp N --seed S [-D name=value ...] [--scale 0.98]

-D values are passed to the scene's <default>s; width, height, max_depth and spp are honoured on any scene,
declared as <default> or not (the check passes them to set the film size, the depth and the samples), by
writing them into the scene's film, integrator and sampler. Other names the file does not use are ignored.
A `moment` integrator (Mitsuba's render tests) renders its wrapped integrator's image in the first channels.
"""
import argparse
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mitsuba as mi
import numpy as np

ANY_SCENE = {"width": ("sensor/film", "integer"), "height": ("sensor/film", "integer"),
             "max_depth": ("integrator", "integer"), "spp": ("sensor/sampler", "integer")}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--spp", type=int, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-D", dest="defines", action="append", default=[])
    ap.add_argument("--scale", type=float, default=1.0, help="multiply the image by this (1: an honest renderer)")
    args = ap.parse_args()
    mi.set_variant("llvm_ad_rgb" if "llvm_ad_rgb" in mi.variants() else "scalar_rgb")
    params = dict(d.split("=", 1) for d in args.defines)
    scene = load(args.scene, params)
    image = np.array(mi.render(scene, spp=args.spp, seed=args.seed))[..., :3] * args.scale
    mi.Bitmap(image.astype(np.float32)).write(str(args.output))


def load(path: Path, params: dict[str, str]):
    """The scene with its <default>s overridden and width, height, max_depth and spp written into it."""
    root = ET.parse(path).getroot()
    folders = [path.parent] + [path.parent / p.get("value", "") for p in root.iter("path")]
    inline(root, folders)
    for name, (where, tag) in ANY_SCENE.items():
        if name in params:
            node = innermost(root, where)
            prop = next((c for c in node if c.get("name") == ("sample_count" if name == "spp" else name)), None)
            if prop is None:
                prop = ET.SubElement(node, tag, name="sample_count" if name == "spp" else name)
            prop.set("value", params[name])
    text = ET.tostring(root, encoding="unicode")
    used = set(re.findall(r"\$(\w+)", text))
    mi.file_resolver().prepend(str(path.parent.resolve()))
    return mi.load_string(text, **{k: v for k, v in params.items() if k in used})


def inline(node: ET.Element, folders: list[Path]) -> None:
    """Every <include> replaced by the included file's elements (so that a film in an included file is set)."""
    for i, child in reversed(list(enumerate(node))):
        if child.tag == "include":
            found = next(d / child.get("filename", "") for d in folders if (d / child.get("filename", "")).is_file())
            included = ET.parse(found).getroot()
            inline(included, folders + [found.parent])
            node[i:i + 1] = list(included)
        else:
            inline(child, folders)


def innermost(root: ET.Element, where: str) -> ET.Element:
    """The element at `where` (created if missing); for the integrator, the one a `moment` wraps."""
    node = root
    for tag in where.split("/"):
        found = node.find(tag)
        if found is None:
            found = ET.SubElement(node, tag, type={"film": "hdrfilm", "sampler": "independent", "sensor": "perspective",
                                                     "integrator": "path"}[tag])
        node = found
        while tag == "integrator" and node.get("type") == "moment" and node.find("integrator") is not None:
            node = node.find("integrator")
    return node


if __name__ == "__main__":
    main()
