"""Adaptive sampling (tracer/adaptive.py) against uniform sampling for the path estimator: RMSE against
render time, where the samples go, and whether the adaptive image is biased.

Both renderers spend the same mean budget (spp samples per pixel). Every point is several independent
images; RMSE is their root-mean-square error against the Mitsuba reference with the reference's own
variance subtracted (as validation.verdict.metrics.rmse), time the shortest render time of the images, without
kernel compilation (each kernel is compiled by one untimed render first; the variants take turns image by
image, and the shortest time is the one least disturbed by other work on the machine). Bias is the mean
signed error per channel of the adaptive images with its standard error, and Welch's per-block test
(validation.verdict.metrics.agreement) against the reference's passes; the same numbers for uniform sampling, and
for the biased variant that chooses a pixel's count from its own pilot samples, show what the test can see.
"""
from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

import tracer  # noqa: E402
from tracer.adaptive import render_adaptive  # noqa: E402
from tracer.imageio import srgb_encode  # noqa: E402
from tracer.rendering import render  # noqa: E402

from ..reports import convergence, plots  # noqa: E402
from ..verdict.metrics import agreement, rel_mse, ssim  # noqa: E402
from ..verdict.references import reference  # noqa: E402

MAX_DEPTH = 4                    # the report's depth 2
FULL = dict(size=128, budgets=(8, 16, 32, 64, 128, 256, 512, 1024), repeats=12, ref=(16, 256), equal=64)
QUICK = dict(size=32, budgets=(8, 16, 32, 64), repeats=4, ref=(16, 64), equal=16)
HARD = 0.05                      # the hardest pixels: the top 5% by the reference's per-sample variance
CRITERIA = ("stddev", "variance", "relative")


def _uniform(scene, spp, seed, **kw):
    return render(scene, "path", spp=spp, seed=seed, max_depth=MAX_DEPTH)


def _adaptive(scene, spp, seed, **kw):
    return render_adaptive(scene, spp=spp, seed=seed, max_depth=MAX_DEPTH, **kw)


METHODS = {"uniform": _uniform, "adaptive": _adaptive}


def _mse(images, ref, mask=None) -> float:
    mask = np.ones(ref.mean.shape[:2], bool) if mask is None else mask
    return float(np.mean([np.mean((im[mask] - ref.mean[mask]) ** 2) for im in images]) - np.mean(ref.var[mask]))


def _rmse(images, ref, mask=None) -> float:
    return float(np.sqrt(max(_mse(images, ref, mask), 0.0)))


def _points(scene, variants: dict, spp, seeds, ref, hard) -> dict[str, dict]:
    """One image per seed of every variant {label: (method, keywords)}, after an untimed compile run of
    each; the variants take turns image by image, so that a load on the machine slows them alike."""
    for method, kw in variants.values():
        METHODS[method](scene, spp, 10**6 + spp, **kw)
    results = {label: [] for label in variants}
    for s in seeds:
        for label, (method, kw) in variants.items():
            results[label].append(METHODS[method](scene, spp, s, **kw))
    return {label: _row(label, spp, rs, ref, hard) for label, rs in results.items()}


def _row(label, spp, results, ref, hard) -> dict:
    images = [r.image for r in results]
    return {"method": label, "spp": spp, "render_seconds": float(min(r.render_seconds for r in results)),
            "rmse": _rmse(images, ref), "rmse_hard": _rmse(images, ref, hard), "rmse_rest": _rmse(images, ref, ~hard),
            "rel_mse": float(np.mean([rel_mse(im, ref) for im in images])),
            "ssim": float(np.mean([ssim(im, ref) for im in images])), "images": images,
            "samples": results[0].settings.get("samples")}


def bias(images: list[np.ndarray], ref) -> dict:
    """Mean signed error per channel over the images, its standard error (the images' spread and the
    reference's own noise), t = bias / se, and Welch's per-block test against the reference's passes."""
    per_image = np.array([np.mean(im - ref.mean, axis=(0, 1), dtype=np.float64) for im in images])   # (K, 3)
    k = len(images)
    pixels = ref.mean.shape[0] * ref.mean.shape[1]
    se = np.sqrt(per_image.var(axis=0, ddof=1) / k + ref.var.sum(axis=(0, 1), dtype=np.float64) / pixels ** 2)
    mean = per_image.mean(axis=0)
    return {"bias": mean, "se": se, "t": mean / se, "relative": mean / ref.mean.mean(axis=(0, 1)),
            "welch": agreement(np.stack(images), ref)}


def measure(scene_file: Path, quick: bool) -> dict:
    cfg = QUICK if quick else FULL
    size = cfg["size"]
    ref = reference(scene_file, MAX_DEPTH, size, *cfg["ref"])
    scene = tracer.load_scene(scene_file, width=size, height=size)
    sample_var = (ref.var * cfg["ref"][0] * cfg["ref"][1]).sum(axis=-1)      # per-sample variance, channel sum
    hard = sample_var >= np.quantile(sample_var, 1 - HARD)
    repeats = cfg["repeats"]
    curves = {m: [] for m in METHODS}
    for i, spp in enumerate(cfg["budgets"]):
        seeds = [1000 * (i + 1) + r for r in range(repeats)]
        rows = _points(scene, {m: (m, {}) for m in METHODS}, spp, seeds, ref, hard)
        for m, row in rows.items():
            curves[m].append(row)
            print(f"adaptive study: {m} {spp} spp: {row['render_seconds']:.3f} s, RMSE {row['rmse']:.4f}", flush=True)
    equal = cfg["equal"]
    seeds = [50_000 + r for r in range(repeats)]
    variants = {"uniform": ("uniform", {})} | {c: ("adaptive", {"criterion": c}) for c in CRITERIA}
    criteria = _points(scene, variants, equal, seeds, ref, hard)
    # The biased variant: a pixel's weight from its own pilot samples, which stay in its mean.
    own = _points(scene, {"own": ("adaptive", {"noise_from": "own"})}, equal, [60_000 + r for r in range(repeats)],
                  ref, hard)["own"]
    # One adaptive image in the time of the uniform one at `equal` spp, for the figure.
    u = next(r for r in curves["uniform"] if r["spp"] == equal)
    a = next(r for r in curves["adaptive"] if r["spp"] == equal)
    same_time_spp = max(3, int(round(equal * u["render_seconds"] / a["render_seconds"])))
    same_time = _points(scene, {"adaptive": ("adaptive", {})}, same_time_spp, [70_000], ref, hard)["adaptive"]
    return {"cfg": cfg, "ref": ref, "hard": hard, "sample_var": sample_var, "curves": curves, "criteria": criteria,
            "own": own, "same_time": same_time, "uniform_equal": u}


def _figure_images(m: dict, path: Path) -> None:
    ref, u, a = m["ref"], m["uniform_equal"], m["same_time"]
    err_u = np.abs(u["images"][0] - ref.mean).mean(-1)
    err_a = np.abs(a["images"][0] - ref.mean).mean(-1)
    top = float(np.percentile(np.concatenate([err_u.ravel(), err_a.ravel()]), 99.5)) or 1e-6
    fig, axes = plt.subplots(2, 4, figsize=(17.5, 8.6))
    panels = [(axes[0, 0], srgb_encode(ref.mean), f"Mitsuba reference ({ref.spp} spp)"),
              (axes[0, 1], srgb_encode(u["images"][0]), f"uniform, {u['spp']} spp, {u['render_seconds']:.3f} s"),
              (axes[0, 2], srgb_encode(a["images"][0]), f"adaptive, {a['spp']} spp, {a['render_seconds']:.3f} s")]
    for ax, img, title in panels:
        ax.imshow(img, interpolation="nearest")
        ax.set_title(title, fontsize=9)
    density = a["samples"] / a["spp"]
    im = axes[1, 0].imshow(density, norm=LogNorm(vmin=max(density.min(), 1e-2), vmax=density.max()), cmap="magma")
    axes[1, 0].set_title("adaptive: samples per pixel / mean (log)", fontsize=9)
    fig.colorbar(im, ax=axes[1, 0], fraction=0.046, pad=0.04)
    for ax, err, label in ((axes[1, 1], err_u, "uniform"), (axes[1, 2], err_a, "adaptive")):
        im = ax.imshow(err, vmin=0, vmax=top, cmap="viridis")
        ax.set_title(f"|{label} - reference| (mean of RGB)", fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    var = m["sample_var"]
    im = axes[0, 3].imshow(var, norm=LogNorm(vmin=max(float(np.percentile(var, 1)), 1e-4), vmax=var.max()),
                           cmap="magma")
    axes[0, 3].set_title("reference: per-sample variance (sum of RGB, log)", fontsize=9)
    fig.colorbar(im, ax=axes[0, 3], fraction=0.046, pad=0.04)
    axes[1, 3].imshow(m["hard"], cmap="gray", interpolation="nearest")
    axes[1, 3].set_title(f"the {HARD:.0%} hardest pixels (largest variance)", fontsize=9)
    for ax in axes.ravel():
        ax.axis("off")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _bias_row(label: str, b: dict) -> str:
    ch = " | ".join(f"{b['bias'][c]:+.5f} ({b['relative'][c] * 100:+.2f}%, t = {b['t'][c]:+.1f})" for c in range(3))
    w = b["welch"]
    return f"| {label} | {ch} | {w.rejected}/{w.tests} (min p {w.min_p:.1e}) |"


def section(scene_file: Path, out: Path, quick: bool = False) -> list[str]:
    start = time.perf_counter()
    scene_file = Path(scene_file)
    m = measure(scene_file, quick)
    cfg, ref, curves = m["cfg"], m["ref"], m["curves"]
    # Fitted on the upper half of the budgets: at the smallest, a launch's fixed cost (and the adaptive
    # pilot's second launch) is a visible part of the time and would steepen the slope.
    fitted = {k: v[len(v) // 2:] for k, v in curves.items()}
    fits = {k: convergence.fit([r["render_seconds"] for r in v], [r["rmse"] for r in v]) for k, v in fitted.items()}
    target = convergence.common_error({k: [r["rmse"] for r in v] for k, v in curves.items()})
    out.mkdir(parents=True, exist_ok=True)
    plots.error_vs_time(curves, fits, target, out / "adaptive_error_vs_time.png")
    _figure_images(m, out / "adaptive_images.png")
    reach = {k: f.seconds_to_reach(target) for k, f in fits.items()}
    size, repeats = cfg["size"], cfg["repeats"]
    hard_n = int(m["hard"].sum())
    lines = [
        f"The path estimator on `{scene_file.name}` at {size} x {size}, max_depth {MAX_DEPTH} (the report's depth "
        f"{MAX_DEPTH - 2}), box filter, with uniform sampling and with `tracer render --adaptive` "
        "(`tracer/adaptive.py`) at the same mean budget: a pilot of half the samples, then the rest in proportion "
        "to the standard deviation estimated from each pixel's 24 neighbours' pilot samples (never its own, which "
        "keeps the image unbiased), water-filled above the pilot. Each point is "
        f"{repeats} independent images; RMSE against Mitsuba's reference ({cfg['ref'][0]} x {cfg['ref'][1]} spp) "
        "with the reference's variance subtracted; time is the shortest of the images' render times (the least "
        "disturbed on a shared machine; the two samplers take turns image by image), without kernel compilation. "
        f"\"Hard\" pixels are the {HARD:.0%} ({hard_n}) with the largest per-sample variance in the reference.", "",
        "| spp | uniform time [s] | uniform RMSE | (hard / rest) | adaptive time [s] | adaptive RMSE | (hard / rest) "
        "| adaptive / uniform RMSE |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for u, a in zip(curves["uniform"], curves["adaptive"]):
        lines.append(f"| {u['spp']} | {u['render_seconds']:.3f} | {u['rmse']:.4f} | {u['rmse_hard']:.3f} / "
                     f"{u['rmse_rest']:.4f} | {a['render_seconds']:.3f} | {a['rmse']:.4f} | {a['rmse_hard']:.3f} / "
                     f"{a['rmse_rest']:.4f} | {a['rmse'] / u['rmse']:.2f} |")
    budgets = [r["spp"] for r in fitted["uniform"]]
    lines += ["", f"| sampling | slope of log RMSE on log time ({budgets[0]}-{budgets[-1]} spp) | time to reach RMSE "
              f"{target:.4f} [s] |", "|---|---:|---:|"]
    for k in curves:
        lines.append(f"| {k} | {fits[k].slope:.3f} | {reach[k]:.3f} |")
    speedup = reach["uniform"] / reach["adaptive"]
    lines += ["", f"To reach the common RMSE {target:.4f} (the larger of the two curves' smallest errors) adaptive "
              f"sampling needs {1 / speedup:.2f}x the time of uniform sampling, from the fitted lines. The dashed "
              f"lines in the figure are those fits ({budgets[0]} spp and up).", "",
              "![RMSE and SSIM against time, uniform and adaptive](adaptive_error_vs_time.png)", "",
              "![where the samples go](adaptive_images.png)", "",
              f"Top: the reference, uniform sampling at {m['uniform_equal']['spp']} spp, adaptive sampling in about "
              f"the same time ({m['same_time']['spp']} spp), and the reference's per-sample variance. Bottom: the "
              "adaptive image's sample density, each image's absolute error (same colour scale), and the pixels "
              "the table calls hard.", ""]
    eq = m["criteria"]
    lines += [f"**Allocation criteria** at {cfg['equal']} spp ({repeats} images each): RMSE is what the default "
              "(`stddev`, n ~ s, the optimum for the summed squared error) minimises; `variance` (n ~ s^2) is the "
              "common heuristic; `relative` minimises the relative MSE (validation.verdict.metrics.rel_mse).", "",
              "| sampling | time [s] | RMSE | relative MSE | 1 - SSIM |", "|---|---:|---:|---:|---:|"]
    for k, r in eq.items():
        label = k if k == "uniform" else f"adaptive, `{k}`"
        lines.append(f"| {label} | {r['render_seconds']:.3f} | {r['rmse']:.4f} | {r['rel_mse']:.5f} | "
                     f"{1 - r['ssim']:.4f} |")
    top_u, top_a = curves["uniform"][-1], curves["adaptive"][-1]
    b_u, b_a, b_own = bias(top_u["images"], ref), bias(top_a["images"], ref), bias(m["own"]["images"], ref)
    lines += ["", f"**Bias.** Mean signed error per channel against the reference (relative to the reference's mean, "
              "and t = bias / standard error, the standard error from the images' spread and the reference's own "
              f"noise), and Welch's test per {4} x {4} block and channel against the reference's passes, "
              "Bonferroni-corrected at family-wise alpha 1e-3. The last row is the biased variant that chooses a "
              "pixel's count from its own pilot samples.", "",
              "| images | R | G | B | Welch: blocks rejected |", "|---|---:|---:|---:|---:|",
              _bias_row(f"uniform, {top_u['spp']} spp x {repeats}", b_u),
              _bias_row(f"adaptive, {top_a['spp']} spp x {repeats}", b_a),
              _bias_row(f"own-pilot variant (biased), {m['own']['spp']} spp x {repeats}", b_own), ""]
    welch = {k: [agreement(np.stack(r["images"]), ref) for r in v] for k, v in curves.items()}
    per_budget = ["{} {}".format(k, ", ".join(
        f"{r['spp']}: {w.rejected}" + (f" (worst t {w.worst_t:+.1f})" if w.rejected else "")
        for r, w in zip(curves[k], welch[k]))) for k in curves]
    dark = all(w.worst_t < 0 for ws in welch.values() for w in ws if w.rejected)
    lines += [f"Welch's test at every budget ({repeats} images against the reference's passes), blocks rejected of "
              f"{welch['uniform'][0].tests}: " + "; ".join(per_budget) + ". With few samples a block's image "
              "means are far from normal where rare bright paths decide them, and the test rejects blocks of "
              "unbiased images too (validation/verdict/stats.py)"
              + (", here always on the dark side (rare bright paths missed)" if dark else "") + "; a bias "
              "would instead be rejected more often as the budget grows."
              + _last_rejections(curves, welch), ""]
    lines += _interpretation(m, fits, speedup, b_a, b_own, scene_file.stem == "hexagon_room")
    lines += ["", f"(Study run time {time.perf_counter() - start:.0f} s.)"]
    return lines


def _last_rejections(curves, welch) -> str:
    last = {k: max([r["spp"] for r, w in zip(curves[k], welch[k]) if w.rejected], default=0) for k in curves}
    if last["adaptive"] > last["uniform"]:
        uniform = f"at {last['uniform']} spp" if last["uniform"] else "none"
        return (f" Adaptive sampling leaves most pixels with about half the budget; its last rejections come at "
                f"{last['adaptive']} spp (uniform sampling's: {uniform}).")
    return ""


def _interpretation(m, fits, speedup, b_a, b_own, room: bool) -> list[str]:
    pairs = list(zip(m["curves"]["uniform"], m["curves"]["adaptive"]))
    ratios = [a["rmse"] / u["rmse"] for u, a in pairs]
    hard_ratio = np.median([a["rmse_hard"] / u["rmse_hard"] for u, a in pairs])
    rest_ratio = np.median([a["rmse_rest"] / u["rmse_rest"] for u, a in pairs])
    t_ratio = np.median([a["render_seconds"] / u["render_seconds"] for u, a in pairs])
    samples = m["same_time"]["samples"]
    share = float(samples[m["hard"]].sum() / samples.sum())
    ref, u_eq = m["ref"], m["uniform_equal"]
    white = (ref.mean >= 1.0).all(axis=-1)                                     # white on display
    sq = np.mean([(im - ref.mean) ** 2 for im in u_eq["images"]], axis=0).sum(axis=-1)
    hard_share, white_share = float(sq[m["hard"]].sum() / sq.sum()), float(sq[white].sum() / sq.sum())
    ssim_worse = sum(a["ssim"] < u["ssim"] for u, a in pairs)
    crit = m["criteria"]
    slopes = (fits["uniform"].slope, fits["adaptive"].slope)
    steady = all(abs(s + 0.5) < 0.1 for s in slopes)
    unbiased = max(abs(b_a["t"])) < 4 and b_a["welch"].passed
    caught = (min(b_own["t"]) < -4) or not b_own["welch"].passed
    faster = (f"{speedup:.2f}x faster to the same RMSE" if speedup > 1
              else f"{1 / speedup:.2f}x slower to the same RMSE")
    return [
        "**Interpretation.** "
        f"At equal samples adaptive sampling's RMSE is {min(ratios):.2f}-{max(ratios):.2f}x uniform sampling's, and "
        f"a render takes a median {t_ratio:.2f}x as long (the pilot is a second launch with a read-back and the "
        "allocation between them; the adaptive samples cost what their pixels' paths cost). "
        f"The gain comes from the hardest {HARD:.0%} of the pixels: in the equal-time image they receive "
        f"{share:.0%} of the samples, and their RMSE is a median {hard_ratio:.2f}x uniform's, while the other "
        f"pixels, left with little more than the pilot's half of the budget, are {rest_ratio:.2f}x as noisy. "
        "The sample density map shows where the pilot found the noise. "
        + ("In this room the hardest pixels are the area light's edges and the light's images in the glass and "
           "the mirror sphere, pixels partly covered by the light (the streaks of the variance and density maps), "
           "which the pilot finds, and scattered pixels, most on the ceiling near the light and around the mirror "
           "sphere, where rare bright paths land. Those rare paths (the isolated bright samples, fireflies, all "
           "over the walls and floor) are what the pilot cannot locate: a pilot sample that caught one sends "
           "samples to its neighbours (the small squares of the density map), most miss them, and those pixels "
           "keep about half of uniform sampling's rate. " if room else "")
        + (f"Both curves fall at the unbiased Monte Carlo rate (slopes {slopes[0]:.2f} and {slopes[1]:.2f} against "
           f"-0.5), so adaptive sampling is a constant factor, {faster}. " if steady else
           f"The fitted slopes are {slopes[0]:.2f} (uniform) and {slopes[1]:.2f} (adaptive) against the unbiased "
           f"rate's -0.5 (timing noise on a shared machine, and fixed costs at small budgets); from the fits "
           f"adaptive sampling is {faster}. ")
        + f"The gain is in linear RMSE: at {u_eq['spp']} spp the hard {HARD:.0%} carry {hard_share:.0%} of uniform "
        f"sampling's squared error, and the pixels at or above 1 in every channel ({white.mean():.0%} of the image, "
        f"white on display whatever their noise) carry {white_share:.0%}. SSIM, computed on the clipped sRGB "
        f"image, sees the rest, and is lower (worse) with adaptive sampling at {ssim_worse} of {len(pairs)} budgets "
        "(right plot); so is the relative MSE, which weights dark pixels up "
        f"({crit['stddev']['rel_mse']:.4f} against uniform's {crit['uniform']['rel_mse']:.4f} at "
        f"{crit['uniform']['spp']} spp). The `relative` criterion makes the opposite trade (criteria table: "
        f"relative MSE {crit['relative']['rel_mse']:.4f}, 1 - SSIM {1 - crit['relative']['ssim']:.4f} against "
        f"uniform's {1 - crit['uniform']['ssim']:.4f}, RMSE {crit['relative']['rmse']:.4f} against "
        f"{crit['uniform']['rmse']:.4f}): which criterion is right depends on the error that matters. "
        + ("The adaptive images show no bias: every channel's mean error is within 4 standard errors of zero and "
           "Welch's test accepts them" if unbiased else
           "The adaptive images did not pass the bias checks here (see the table)")
        + ("; the same checks reject the variant that chooses a pixel's count from its own pilot samples (too "
           "dark, as the module docstring of `tracer/adaptive.py` explains)." if caught else
           "; the checks did not resolve the own-pilot variant's bias at this size.")]
