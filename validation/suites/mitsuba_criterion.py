"""Mitsuba's own render-test criterion beside the check's, on the scenes of Mitsuba's render tests.

Mitsuba's render tests (mitsuba-renderer/mitsuba3, src/render/tests/test_renders.py; protocol as its
documentation describes it) render a scene once at spp = 2,000,000 // pixels and compare it with a
32,000-spp reference mean and per-sample variance image (refs/<name>_ref_rgb.exr, _ref_rgb_var.exr in
mitsuba-renderer/mitsuba-data): all three converted to CIE XYZ, the variance floored at 1e-4, per pixel and
channel z = |mean - ref| sqrt(spp / var) and p = 2 (1 - Phi(z)); Sidak's level 1 - (1 - 0.01)^(1 / pixels);
the test passes when at least 99.75% of the pixels (the channels' passing counts summed, divided by 3) have
p above it.

At the same sample budget, the check renders PASSES passes of spp // PASSES samples on each side. Both are
run on the same renders of the renderer under test (Mitsuba's path, scaled by s as the example renderer's
--scale), repetition by repetition, so their power on a bias of 1 - s is compared like for like.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import stats as sps

from ..verdict import protocol
from .calibration import CACHE, cached_repetitions
from ..verdict.renderers import MitsubaRenderer
from ..verdict.scenefile import plan
from ..verdict.stats import block_means, compare

BUDGET = 2_000_000            # samples per image in Mitsuba's render tests
ALPHA = 0.01                  # Mitsuba's level over the image (Sidak per pixel)
PASS_FRACTION = 0.9975        # of the pixels that must pass
VARIANCE_FLOOR = 1e-4
SCALES = (1.0, 0.99, 0.98, 0.97, 0.95, 0.9)
SEED = 90_000
SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423],     # linear sRGB (D65) to CIE XYZ
                        [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]])


def mitsuba_passes(image: np.ndarray, ref: np.ndarray, var: np.ndarray, spp: int) -> bool:
    """Mitsuba's criterion on a (H, W, 3) linear RGB image rendered at `spp` against the reference's mean
    and per-sample variance."""
    x, r, v = (a[..., :3] @ SRGB_TO_XYZ.T for a in (image, ref, var))
    z = np.abs(x - r) * np.sqrt(spp / np.maximum(v, VARIANCE_FLOOR))
    p = 2 * sps.norm.sf(z)
    pixels = image.shape[0] * image.shape[1]
    level = 1 - (1 - ALPHA) ** (1 / pixels)
    return (p > level).sum() / 3 >= PASS_FRACTION * pixels


def renders(scene: Path, repetitions: int, cache: Path = CACHE) -> dict[str, np.ndarray]:
    """Per repetition both sides' PASSES passes at the budget's spp // PASSES (test: full images, ref:
    block means); cached, extended as asked."""
    scene_plan = plan(scene, size=None)
    spp = BUDGET // (scene_plan.width * scene_plan.height) // protocol.PASSES
    key = scene_plan.content_key(spp=spp, passes=protocol.PASSES, seed=SEED, design="mitsuba-criterion")
    path = cache / f"criterion-{scene.stem}-{key}.npz"
    renderer = MitsubaRenderer()

    def one(r: int) -> dict[str, np.ndarray]:
        return {"test": renderer.passes(scene_plan, protocol.PASSES, spp, SEED + 1000 * r),
                "ref": block_means(renderer.passes(scene_plan, protocol.PASSES, spp, SEED + 1000 * r + 500),
                                   protocol.BLOCK).astype(np.float32)}

    return cached_repetitions(path, repetitions, f"criterion {scene.stem}", one) | {"spp": spp}


def measure(scene: Path, repetitions: int) -> list[dict]:
    """Per scale: how often Mitsuba's criterion fails and how often the check disagrees (alpha 1e-3, one
    stage at the same budget), with the check's median detectable bias of the image mean."""
    from tracer.imageio import read_exr

    refs = scene.parent / "refs"
    stem = scene.stem.removesuffix("_path")
    ref, var = read_exr(refs / f"{stem}_ref_rgb.exr"), read_exr(refs / f"{stem}_ref_rgb_var.exr")
    data = renders(scene, repetitions)
    rows = []
    for s in SCALES:
        checks = [compare(block_means(t * s, protocol.BLOCK), b, protocol.ALPHA) for t, b in zip(data["test"], data["ref"])]
        rows.append({"scene": scene.name, "scale": s, "n": repetitions, "spp": int(data["spp"]) * protocol.PASSES,
                     "mitsuba_fails": sum(not mitsuba_passes(t.mean(0) * s, ref, var, int(data["spp"]) * protocol.PASSES)
                                          for t in data["test"]),
                     "check_disagrees": sum(c.verdict == "disagree" for c in checks),
                     "detectable_image": float(np.median([c.detectable_image.max() for c in checks]))})
    return rows


def markdown(rows: list[dict]) -> list[str]:
    lines = [SECTION, "",
             "Mitsuba's render-test criterion (per-pixel z-test of one image at 2,000,000 samples against the "
             "32,000-spp reference and its variance, 99.75% of the pixels passing at a Sidak level of 0.01; "
             "validation/suites/mitsuba_criterion.py) and the check (16 passes of the same budget's spp // 16 each side, "
             "alpha 1e-3, one stage, no margin) on the same renders of Mitsuba's path scaled by s (the example "
             "renderer's `--scale`): how often each catches the bias 1 - s. Both use the same spp (the budget's "
             "2,000,000 // pixels, rounded down to a multiple of 16), and the check renders as many again for its "
             "own reference where Mitsuba's criterion reads its stored 32,000-spp one. The reference images come "
             "from a local copy of mitsuba-renderer/mitsuba-data.", "",
             "| scene | spp | scale | Mitsuba's criterion fails | the check disagrees | check's detectable bias, image mean (median, worst channel) |",
             "|---|---:|---:|---|---|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['spp']} | {r['scale']:g} | {r['mitsuba_fails']}/{r['n']} | "
                     f"{r['check_disagrees']}/{r['n']} | {r['detectable_image']:.1%} |")
    return lines


SECTION = "## Mitsuba's render-test criterion beside the check"


def update(out: Path, mitsuba_data: Path, repetitions: int) -> Path:
    """Measures the render-test scenes of SCENES in a copy of mitsuba-data and writes the section into `out`."""
    from ..reports.provenance import replace_section, write_json

    rows = [r for name in SCENES for r in measure(mitsuba_data / name, repetitions)]
    write_json(out.with_name("calibration_criterion.json"), rows)
    return replace_section(out, SECTION, markdown(rows), before="## Time per check")


SCENES = ("tests/scenes/bsdf_spheres/test_arealight_path.xml",)   # in mitsuba-renderer/mitsuba-data
