"""A stand-in for "your own renderer", for `validate check --renderer`: renders a scene with Mitsuba 3's Python
API and writes an EXR, optionally scaling the image (a deliberately wrong renderer).

    python examples/mitsuba_renderer.py SCENE.xml -o OUT.exr --spp N --seed S [-D name=value ...] [--scale 0.98]

-D values are passed to the scene's <default>s; those the file does not use are ignored (so the scene must
declare width, height and max_depth for the check's film size and depth to reach it).
"""
import argparse
import re
from pathlib import Path

import mitsuba as mi
import numpy as np


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
    used = set(re.findall(r"\$(\w+)", args.scene.read_text()))
    params = dict(d.split("=", 1) for d in args.defines)
    scene = mi.load_file(str(args.scene), **{k: v for k, v in params.items() if k in used})
    image = np.array(mi.render(scene, spp=args.spp, seed=args.seed))[..., :3] * args.scale
    mi.Bitmap(image.astype(np.float32)).write(str(args.output))


if __name__ == "__main__":
    main()
