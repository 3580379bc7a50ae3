"""Denoising with Intel Open Image Denoise (OIDN), judged at equal time against the Mitsuba reference.

The path tracer renders the room at a range of sample counts. Each image up to a few hundred samples is
also denoised by OIDN, once from the colour alone and once guided by the albedo and normal AOVs
(tracer.aov). A denoised image's time is its render time plus the AOVs' and OIDN's, and it is compared
with the noisy image that took the same time (log-log interpolation along the noisy curve), on the whole
image and per region of the picture, to find where the denoiser removes detail that is really there:
there its error exceeds the noisy image's at the same time, and stops falling as samples are added.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

import tracer  # noqa: E402
from tracer.aov import render_aovs  # noqa: E402
from tracer.camera import primary_rays  # noqa: E402
from tracer.denoise import denoise  # noqa: E402
from tracer.geometry import SceneGeometry  # noqa: E402
from tracer.materials import CONDUCTOR, DIELECTRIC, DIFFUSE, SurfaceBSDF  # noqa: E402
from tracer.imageio import srgb_encode  # noqa: E402
from tracer.integrators.direct import sample_direct  # noqa: E402
from tracer.jit import NO_PRIM, UInt32  # noqa: E402
from tracer.rendering import render  # noqa: E402
from tracer.sampling import seeded_rng  # noqa: E402

from .filters import edge_mask  # noqa: E402
from ..verdict.metrics import ssim  # noqa: E402
from ..verdict.references import reference  # noqa: E402

MAX_DEPTH = 4           # the report's depth 2
AOV_SPP = 8
LIGHT = 2.0             # reference radiance above which a pixel shows the light (diffuse surfaces stay below)
LIGHT_INSIDE = "light seen directly, inside its outline"
METHODS = {"noisy": "noisy", "colour": "denoised, colour only", "aov": "denoised, colour + albedo + normal"}


@dataclass(frozen=True)
class Config:
    size: int
    ref_spp: int                 # per pass of the 16-pass Mitsuba reference
    noisy_spps: tuple[int, ...]
    denoise_spps: tuple[int, ...]
    repeats: int                 # independent images per point: errors are root-mean-square, times minima
    image_spp: int               # the figures' denoised image


FULL = Config(128, 256, tuple(2 ** k for k in range(13)), tuple(2 ** k for k in range(9)), 3, 16)
QUICK = Config(32, 64, tuple(2 ** k for k in range(11)), tuple(2 ** k for k in range(7)), 1, 4)


# ---- regions of the picture ------------------------------------------------------------------------------
def _pixel_samples(scene: tracer.Scene, spp: int):
    """Per pixel and jittered camera ray: the object hit, the material kind, whether it is a light's emitting
    side, whether it is a lit diffuse surface, and whether one shadow ray to a uniform light point from there
    is unoccluded and facing."""
    geo, cam = SceneGeometry(scene), scene.camera
    sample = dr.arange(UInt32, cam.width * cam.height * spp)
    rng = seeded_rng(sample, 0x5EED)
    o, d, t_min, t_max, _, _ = primary_rays(cam, sample // spp, rng)
    surf = geo.surface(geo.closest_hit(o, d, t_min, t_max, UInt32(NO_PRIM)))
    bsdf = SurfaceBSDF(geo.materials, surf, -d, surf.valid)
    kind = bsdf.kind
    diffuse = surf.valid & (kind == DIFFUSE) & bsdf.lit
    ds = sample_direct(geo, surf, bsdf, rng.next_float32(), rng.next_float32(), rng.next_float32(), diffuse)
    seen = diffuse & (dr.max(ds.value) > 0)
    emitter = dr.max(geo.emitted(surf, -d)) > 0
    shape = (cam.height, cam.width, spp)
    prim = surf.prim.numpy().astype(np.int64)
    table = np.array([i for i in range(len(scene.rectangles))]
                     + [len(scene.rectangles) + k for k, m in enumerate(scene.meshes) for _ in m.faces]
                     + [len(scene.rectangles) + len(scene.meshes) + k for k in range(len(scene.spheres))])
    obj = np.where(prim == NO_PRIM, -1, table[np.minimum(prim, len(table) - 1)])
    arrays = [np.asarray(a.numpy()).reshape(shape) for a in (kind, surf.valid, emitter, diffuse, seen)]
    return (obj.reshape(shape), *arrays)


def regions(scene: tracer.Scene, ref, spp: int = 64) -> dict[str, np.ndarray]:
    """Exclusive pixel masks, each pixel in the first region it qualifies for. The light's pixels (reference
    above LIGHT): inside its outline (every camera ray hits it, so every image is exact there), its
    outline (some camera rays hit it), its images in the mirror and in the glass (by the sphere most of
    the pixel's rays hit). Then the mirror sphere and the glass sphere (half the camera rays hit it), the
    tetrahedron's edges (filter_study.edge_mask), other object edges (no object covers 98% of the pixel),
    penumbrae (2% to 98% of shadow rays from the surface reach the light), no direct light (ceiling,
    umbrae: under 2%), and directly lit flat surfaces."""
    obj, kind, valid, emitter, diffuse, seen = _pixel_samples(scene, spp)
    cover = np.max([(obj == o).mean(-1) for o in np.unique(obj)], axis=0)
    n_diffuse = diffuse.sum(-1)
    visible = np.where(n_diffuse > 0, seen.sum(-1) / np.maximum(n_diffuse, 1), 0.0)
    try:
        tetra = edge_mask(scene)
    except ValueError:          # a scene without the tetrahedron
        tetra = np.zeros(obj.shape[:2], bool)
    bright = ref.mean.max(-1) > LIGHT
    mirror = (valid & (kind == CONDUCTOR)).mean(-1)
    glass = (valid & (kind == DIELECTRIC)).mean(-1)
    candidates = [
        (LIGHT_INSIDE, bright & emitter.all(-1)),
        ("light's outline", bright & emitter.any(-1)),
        ("light's image in the mirror sphere", bright & (mirror >= glass)),
        ("light's image in the glass sphere", bright),
        ("mirror sphere (reflections)", mirror >= 0.5),
        ("glass sphere (refractions)", glass >= 0.5),
        ("tetrahedron edges", tetra),
        ("other object edges", cover < 0.98),
        ("penumbrae (partly lit)", (visible > 0.02) & (visible < 0.98)),
        ("no direct light (ceiling, umbrae)", visible <= 0.02),
        ("directly lit, flat", np.ones(obj.shape[:2], bool)),
    ]
    masks, taken = {}, np.zeros(obj.shape[:2], bool)
    for name, mask in candidates:
        masks[name] = mask & ~taken
        taken |= mask
    return masks


# ---- measurement -------------------------------------------------------------------------------------------
def _errors(images: list[np.ndarray], ref, masks: dict[str, np.ndarray]) -> dict:
    """RMSE (root of the mean over images of the MSE, less the reference's variance) on the whole image, off
    the light and per region; SSIM averaged over the images."""
    def rms(mask):
        mse = np.mean([np.mean((im[mask] - ref.mean[mask]) ** 2) for im in images]) - np.mean(ref.var[mask])
        return float(np.sqrt(max(mse, 0.0)))

    light = ref.mean.max(-1) > LIGHT
    ssim_mean = float(np.mean([ssim(im, ref) for im in images]))
    return {"rmse": rms(np.ones(light.shape, bool)), "rmse_off": rms(~light), "ssim": ssim_mean,
            "ssim_loss": 1.0 - ssim_mean,
            "regions": {name: rms(mask) for name, mask in masks.items() if mask.any()},
            "bias": {name: float(np.mean([np.mean(im[mask] - ref.mean[mask]) for im in images]))
                     for name, mask in masks.items() if mask.any()}}


def _timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


def measure(scene_file: Path, cfg: Config) -> dict:
    ref = reference(scene_file, MAX_DEPTH, cfg.size, 16, cfg.ref_spp)
    scene = tracer.load_scene(scene_file, width=cfg.size, height=cfg.size)
    masks = regions(scene, ref)
    aovs = [render_aovs(scene, AOV_SPP, seed=100 + r) for r in range(cfg.repeats + 1)][1:]   # the first compiles
    aov_seconds = min(a.render_seconds for a in aovs)
    _, setup = _timed(denoise, ref.mean.astype(np.float32), aovs[0].albedo, aovs[0].normal)  # device, filter, weights
    _timed(denoise, ref.mean.astype(np.float32))
    rows, images, oidn = [], {}, {"colour": [], "aov": []}
    for spp in cfg.noisy_spps:
        runs = [render(scene, "path", spp=spp, seed=1 + r, max_depth=MAX_DEPTH) for r in range(cfg.repeats)]
        noisy = [r.image for r in runs]
        render_s = min(r.render_seconds for r in runs)
        rows.append({"method": "noisy", "spp": spp, "seconds": render_s, **_errors(noisy, ref, masks)})
        images[("noisy", spp)] = noisy[0]
        if spp not in cfg.denoise_spps:
            continue
        for method in ("colour", "aov"):
            outs, secs = [], []
            for im, aov in zip(noisy, aovs):
                out, s = _timed(denoise, im, *((aov.albedo, aov.normal) if method == "aov" else ()))
                outs.append(out)
                secs.append(s)
            oidn[method] += secs
            extra = min(secs) + (aov_seconds if method == "aov" else 0.0)
            rows.append({"method": method, "spp": spp, "seconds": render_s + extra, **_errors(outs, ref, masks)})
            images[(method, spp)] = outs[0]
    return {"rows": rows, "images": images, "ref": ref, "masks": masks, "aov": aovs[0], "aov_seconds": aov_seconds,
            "oidn_seconds": {m: min(s) for m, s in oidn.items()}, "setup_seconds": setup}


def noisy_at(rows: list[dict], seconds: float, value) -> float:
    """A noisy-image metric at a given time: log-log interpolation between the measured sample counts
    (held at the end points outside them)."""
    pts = sorted((r["seconds"], value(r)) for r in rows if r["method"] == "noisy")
    t = np.log([p[0] for p in pts])
    v = np.log(np.maximum([p[1] for p in pts], 1e-9))
    return float(np.exp(np.interp(np.log(seconds), t, v)))


# ---- figures -------------------------------------------------------------------------------------------------
def _figure_curves(rows: list[dict], path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.3))
    keys = [("rmse", "RMSE, whole image"), ("rmse_off", "RMSE off the light"), ("ssim", "1 - SSIM (sRGB)")]
    for method, label in METHODS.items():
        r = [x for x in rows if x["method"] == method]
        t = [x["seconds"] for x in r]
        for ax, (key, _) in zip(axes, keys):
            v = [1 - x[key] if key == "ssim" else x[key] for x in r]
            ax.loglog(t, v, "o-" if method == "noisy" else "s-", ms=4, label=label)
            for x, tx, vx in zip(r, t, v):
                if method != "noisy" or x["spp"] in (1, 16, 256, 4096):
                    ax.annotate(str(x["spp"]), (tx, vx), fontsize=6, xytext=(2, 2), textcoords="offset points")
    for ax, (_, title) in zip(axes, keys):
        ax.set(xlabel="time per image [s] (render + AOVs + OIDN)", title=title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("error against the Mitsuba reference (labels: spp)")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _equal_time_spp(rows: list[dict], seconds: float) -> int:
    noisy = [r for r in rows if r["method"] == "noisy"]
    return min(noisy, key=lambda r: abs(np.log(r["seconds"] / seconds)))["spp"]


def _figure_images(m: dict, spp: int, path: Path) -> int:
    rows, images, ref = m["rows"], m["images"], m["ref"].mean
    den = next(r for r in rows if r["method"] == "aov" and r["spp"] == spp)
    same_time = _equal_time_spp(rows, den["seconds"])
    panels = [(f"noisy, {spp} spp", images[("noisy", spp)]),
              (f"denoised (+ AOVs), {spp} spp, {den['seconds']:.3f} s", images[("aov", spp)]),
              (f"noisy, {same_time} spp (about the same time)", images[("noisy", same_time)]),
              ("Mitsuba reference", ref)]
    fig, axes = plt.subplots(2, 4, figsize=(17, 8.8))
    norm = LogNorm(vmin=1e-3, vmax=10)
    for k, (title, img) in enumerate(panels):
        axes[0, k].imshow(srgb_encode(img), interpolation="nearest")
        axes[0, k].set_title(title, fontsize=9)
        if k < 3:
            heat = axes[1, k].imshow(np.maximum(np.abs(img - ref).mean(-1), 1e-3), cmap="magma", norm=norm,
                                     interpolation="nearest")
            axes[1, k].set_title(f"|error|, {title.split(',')[0]} ({title.split(', ')[1]})", fontsize=9)
    region_map = np.zeros(ref.shape[:2])
    cmap = plt.get_cmap("tab20", 20)
    for i, mask in enumerate(m["masks"].values()):
        region_map[mask] = i
    axes[1, 3].imshow(region_map, cmap=cmap, vmin=-0.5, vmax=19.5, interpolation="nearest")
    axes[1, 3].set_title("regions of the per-region table", fontsize=9)
    axes[1, 3].legend(handles=[Patch(color=cmap(i), label=name) for i, name in enumerate(m["masks"])],
                      fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    fig.colorbar(heat, ax=axes[1, :3], fraction=0.02, pad=0.01, label="|image - reference|, mean of RGB")
    for ax in axes.ravel():
        ax.axis("off")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return same_time


def _crop(mask: np.ndarray, pad: int) -> tuple[slice, slice]:
    ys, xs = np.nonzero(mask)
    return (slice(max(ys.min() - pad, 0), ys.max() + pad + 1), slice(max(xs.min() - pad, 0), xs.max() + pad + 1))


def _figure_crops(m: dict, spp: int, same_time: int, path: Path) -> list[str]:
    names = [n for n in ("mirror sphere (reflections)", "glass sphere (refractions)", "tetrahedron edges")
             if m["masks"][n].any()]
    cols = [(f"noisy, {same_time} spp (same time)", m["images"][("noisy", same_time)]),
            (f"denoised (+ AOVs), {spp} spp", m["images"][("aov", spp)]), ("Mitsuba reference", m["ref"].mean)]
    fig, axes = plt.subplots(len(names), 3, figsize=(10, 3.4 * len(names)), squeeze=False)
    pad = max(2, m["ref"].mean.shape[0] // 32)
    for i, name in enumerate(names):
        crop = _crop(m["masks"][name], pad)
        for j, (title, img) in enumerate(cols):
            axes[i, j].imshow(srgb_encode(img[crop]), interpolation="nearest")
            axes[i, j].set_title(f"{name}: {title}" if j == 0 else title, fontsize=8)
            axes[i, j].axis("off")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return names


def _figure_aovs(aov, path: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(8.5, 4.3))
    axes[0].imshow(np.clip(aov.albedo, 0, 1), interpolation="nearest")
    axes[0].set_title(f"albedo AOV ({aov.spp} spp)", fontsize=9)
    axes[1].imshow(np.clip(aov.normal * 0.5 + 0.5, 0, 1), interpolation="nearest")
    axes[1].set_title("normal AOV (world space, shown as n/2 + 1/2)", fontsize=9)
    for ax in axes:
        ax.axis("off")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# ---- the report section ---------------------------------------------------------------------------------------
def section(scene_file: Path, out: Path, quick: bool = False) -> list[str]:
    cfg = QUICK if quick else FULL
    start = time.perf_counter()
    m = measure(Path(scene_file), cfg)
    out.mkdir(parents=True, exist_ok=True)
    rows = m["rows"]
    _figure_curves(rows, out / "denoise_error_vs_time.png")
    image_spp = cfg.image_spp
    same_time = _figure_images(m, image_spp, out / "denoise_images.png")
    crop_names = _figure_crops(m, image_spp, same_time, out / "denoise_crops.png")
    _figure_aovs(m["aov"], out / "denoise_aovs.png")
    return _markdown(m, cfg, same_time, crop_names, time.perf_counter() - start)


def _markdown(m: dict, cfg: Config, same_time: int, crop_names: list[str], run_seconds: float) -> list[str]:
    rows = m["rows"]
    noisy = {r["spp"]: r for r in rows if r["method"] == "noisy"}
    den = {(r["method"], r["spp"]): r for r in rows if r["method"] != "noisy"}
    oidn = m["oidn_seconds"]
    per_sample = statistics.median(r["seconds"] / r["spp"] for r in noisy.values() if r["spp"] >= 64) \
        if any(s >= 64 for s in noisy) else noisy[max(noisy)]["seconds"] / max(noisy)
    lines = [
        f"The path tracer at {cfg.size} x {cfg.size}, `max_depth` {MAX_DEPTH} (the report's depth {MAX_DEPTH - 2}), "
        f"box filter, against Mitsuba's reference (16 x {cfg.ref_spp} spp). Open Image Denoise {_oidn_version()} "
        "(`pyoidn`, CPU device, `RT` filter, HDR, quality high, `cleanAux` off because the AOVs are themselves "
        f"Monte Carlo estimates) denoises every image up to {max(cfg.denoise_spps)} spp, from the colour alone and "
        f"guided by the albedo and normal AOVs ({AOV_SPP} spp, first non-specular surface through mirror and "
        f"glass). Errors are root-mean-square over {cfg.repeats} independent images per point; times are the "
        "fastest of those runs (the machine is shared, the minimum is the least disturbed), without Dr.Jit's "
        "compile time.", "",
        f"Cost: the AOVs take {m['aov_seconds'] * 1e3:.1f} ms, OIDN {oidn['colour'] * 1e3:.0f} ms (colour only) and "
        f"{oidn['aov'] * 1e3:.0f} ms (with AOVs) per image; its one-time set-up (device, filter, weights) "
        f"{m['setup_seconds'] * 1e3:.0f} ms is not counted, as Dr.Jit's compile time is not. One sample per pixel "
        f"costs about {per_sample * 1e3:.2f} ms here, so denoising with AOVs costs as much time as "
        f"{(m['aov_seconds'] + oidn['aov']) / per_sample:.0f} more samples per pixel.", "",
        "**Whole image, at equal time.** *Noisy at equal time* interpolates the noisy curve (log-log) at the "
        "denoised image's time (render + AOVs + OIDN), for the variant with AOVs.", "",
        "| spp | time with AOVs + OIDN [s] | RMSE noisy, same spp | RMSE denoised, colour | RMSE denoised, + AOVs "
        "| RMSE noisy, equal time | SSIM noisy, same spp | SSIM denoised, colour | SSIM denoised, + AOVs "
        "| SSIM noisy, equal time |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for spp in cfg.denoise_spps:
        c, a, n = den[("colour", spp)], den[("aov", spp)], noisy[spp]
        lines.append(f"| {spp} | {a['seconds']:.3f} | {n['rmse']:.4f} | {c['rmse']:.4f} | {a['rmse']:.4f} | "
                     f"{noisy_at(rows, a['seconds'], lambda r: r['rmse']):.4f} | {n['ssim']:.3f} | {c['ssim']:.3f} | "
                     f"{a['ssim']:.3f} | {1 - noisy_at(rows, a['seconds'], lambda r: 1 - r['ssim']):.3f} |")
    n_light = int((m["ref"].mean.max(-1) > LIGHT).sum())
    lines += ["", f"**Off the light** (leaving out the {n_light} pixels where the reference exceeds {LIGHT:g}: the "
              "light seen directly or in the mirror and glass):", "",
              "| spp | RMSE noisy, same spp | RMSE denoised, colour | RMSE denoised, + AOVs | RMSE noisy, equal time |",
              "|---:|---:|---:|---:|---:|"]
    for spp in cfg.denoise_spps:
        c, a, n = den[("colour", spp)], den[("aov", spp)], noisy[spp]
        lines.append(f"| {spp} | {n['rmse_off']:.4f} | {c['rmse_off']:.4f} | {a['rmse_off']:.4f} | "
                     f"{noisy_at(rows, a['seconds'], lambda r: r['rmse_off']):.4f} |")
    lines += ["", "![error against time, noisy and denoised](denoise_error_vs_time.png)", "",
              "![noisy, denoised and reference images with their error maps](denoise_images.png)", "",
              f"Top: {cfg.image_spp} spp noisy, the same denoised with AOVs, the noisy image of about the same "
              f"time ({same_time} spp), the reference. Bottom: their absolute error (log scale) and the regions of "
              "the next table.", ""]
    lines += _region_lines(m, cfg)
    if crop_names:
        lines += ["", "![crops: mirror, glass, tetrahedron edges](denoise_crops.png)", "",
                  f"Crops ({', '.join(crop_names)}), nearest-neighbour enlarged: noisy at equal time, denoised with "
                  f"AOVs at {cfg.image_spp} spp, reference.", "",
                  "![the AOVs](denoise_aovs.png)", ""]
    lines += _interpretation(m, cfg)
    lines += ["", f"(Study run time {run_seconds:.0f} s.)"]
    return lines


def _region_lines(m: dict, cfg: Config) -> list[str]:
    rows, masks = m["rows"], m["masks"]
    points = [s for s in (4, cfg.image_spp, max(cfg.denoise_spps)) if s in cfg.denoise_spps]
    points = sorted(set(points))
    den = {r["spp"]: r for r in rows if r["method"] == "aov"}
    head = "| region | pixels | " + " | ".join(f"{s} spp: noisy equal time / denoised (ratio)" for s in points) \
        + f" | bias denoised, {points[-1]} spp |"
    lines = ["**Per region, at equal time** (denoised with AOVs; ratio > 1: the denoiser's error exceeds the noise "
             "it removed, it took detail away). The bias is the mean signed error of the denoised image there.", "",
             head, "|---|---:|" + "---:|" * len(points) + "---:|"]
    for name, mask in masks.items():
        if not mask.any():
            continue
        cells = []
        for s in points:
            d = den[s]["regions"][name]
            n = noisy_at(rows, den[s]["seconds"], lambda r: r["regions"][name])
            cells.append(f"{n:.4f} / {d:.4f} ({_ratio(d, n)})")
        lines.append(f"| {name} | {int(mask.sum())} | " + " | ".join(cells)
                     + f" | {den[points[-1]]['bias'][name]:+.4f} |")
    return lines


def _interpretation(m: dict, cfg: Config) -> list[str]:
    rows, masks = m["rows"], m["masks"]
    den = [r for r in rows if r["method"] == "aov"]
    col = {r["spp"]: r for r in rows if r["method"] == "colour"}
    same = {r["spp"]: r for r in rows if r["method"] == "noisy"}

    def eq(r, key):
        return noisy_at(rows, r["seconds"], lambda x: x[key])

    def eq_region(r, name):
        return noisy_at(rows, r["seconds"], lambda x: x["regions"][name])

    def fmt(spps):
        return ", ".join(str(s) for s in spps) + " spp" if spps else "no sample count"

    wins = [r["spp"] for r in den if r["rmse"] < eq(r, "rmse")]
    wins_off = [r["spp"] for r in den if r["rmse_off"] < eq(r, "rmse_off")]
    wins_ssim = [r["spp"] for r in den if r["ssim"] > 1 - eq(r, "ssim_loss")]
    ratios_off = [r["rmse_off"] / max(eq(r, "rmse_off"), 1e-9) for r in den]
    aov_better = [r["spp"] for r in den if r["rmse_off"] < col[r["spp"]]["rmse_off"]]
    last, shown = den[-1], next(r for r in den if r["spp"] == cfg.image_spp)
    bright = m["ref"].mean.max(-1) > LIGHT
    light_sq = sum(mask.sum() * last["regions"][n] ** 2 for n, mask in masks.items()
                   if n in last["regions"] and mask.any() and not (mask & ~bright).any())
    share = light_sq / max(bright.size * last["rmse"] ** 2, 1e-12)

    def worse(r):
        out = [(n, r["regions"][n], eq_region(r, n)) for n in masks if n in r["regions"]]
        return ", ".join(f"{n} ({_ratio(d, q)})" for n, d, q in out if d > q) or "none"

    lines = [
        "What the measurements say (this run):", "",
        f"- Whole image, RMSE at equal time: denoising with AOVs is ahead at {fmt(wins)} of the {len(den)} measured "
        f"({fmt([r['spp'] for r in den])}). The light's {int(bright.sum())} pixels "
        f"({100 * bright.mean():.1f}% of the image, radiance up to 32 against about 1 elsewhere) carry "
        f"{100 * share:.0f}% of the denoised image's squared error at {last['spp']} spp.",
        f"- Off the light, RMSE at equal time: ahead at {fmt(wins_off)}; the denoised error is "
        f"{min(ratios_off):.2f} to {max(ratios_off):.2f} times the noisy image's at the same time.",
        f"- SSIM at equal time: ahead at {fmt(wins_ssim)} (SSIM is measured against the reference, whose own "
        f"noise at {m['ref'].spp} spp keeps it below 1).",
        f"- The AOVs bring the off-light RMSE below the colour-only denoiser's at {fmt(aov_better)}.",
        f"- Regions where the denoiser's error exceeds the noisy image's at equal time, i.e. where it removes or "
        f"alters detail that is there: at {shown['spp']} spp {worse(shown)}; at {last['spp']} spp {worse(last)}.",
    ]
    if LIGHT_INSIDE in last["regions"]:
        lines.append(
            f"- Inside the light's outline every noisy image is exact (RMSE {same[last['spp']]['regions'][LIGHT_INSIDE]:.4f} "
            f"at {last['spp']} spp: each sample sees the emission); the denoised image's RMSE there is "
            f"{last['regions'][LIGHT_INSIDE]:.4f} (bias {last['bias'][LIGHT_INSIDE]:+.4f}): OIDN changes pixels "
            "that carry no noise at all.")
    return lines


def _ratio(denoised: float, noisy: float) -> str:
    return f"{denoised / noisy:.2f}x" if noisy > 1e-6 else "noisy exact"


def _oidn_version() -> str:
    try:
        from importlib.metadata import version

        return version("pyoidn")
    except Exception:  # noqa: BLE001
        return "(version unknown)"
