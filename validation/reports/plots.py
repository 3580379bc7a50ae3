"""The report's figures (matplotlib, Agg, PNG): error against time, error against depth, image panels."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tracer.imageio import srgb_encode  # noqa: E402

from .convergence import Fit  # noqa: E402


def _save(fig, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def error_vs_time(curves: dict[str, list[dict]], fits: dict[str, Fit], target: float | None, path: Path) -> None:
    """RMSE and 1 - SSIM against render seconds, log-log, one curve per estimator with its fitted slope."""
    fig, (ax_rmse, ax_ssim) = plt.subplots(1, 2, figsize=(11, 4.2))
    for label, rows in curves.items():
        t = np.array([r["render_seconds"] for r in rows])
        line, = ax_rmse.loglog(t, [r["rmse"] for r in rows], "o-", label=f"{label}: slope {fits[label].slope:.2f}")
        ax_rmse.loglog(t, fits[label].predict(t), "--", color=line.get_color(), alpha=0.6)
        ax_ssim.loglog(t, [1 - r["ssim"] for r in rows], "o-", color=line.get_color(), label=label)
    if target is not None:
        ax_rmse.axhline(target, color="grey", lw=0.8, ls=":", label=f"common RMSE {target:.3g}")
    ax_rmse.set(xlabel="render time per image [s]", ylabel="RMSE (linear radiance)", title="RMSE against time")
    ax_ssim.set(xlabel="render time per image [s]", ylabel="1 - SSIM (sRGB)", title="SSIM against time")
    for ax in (ax_rmse, ax_ssim):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    _save(fig, path)


def error_vs_depth(depths: list[str], share: list[float], curves: dict[str, list[tuple[str, float]]],
                   path: Path) -> None:
    """Left: the share of the unbounded image's mean radiance each added bounce carries (from the
    references). Right: RMSE against max_depth per estimator."""
    fig, (ax_share, ax_rmse) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax_share.bar(depths, np.asarray(share) * 100, color="tab:orange")
    ax_share.set(xlabel="max_depth (segments)", ylabel="% of unbounded mean radiance",
                 title="what each added bounce carries (Mitsuba reference)")
    for label, points in curves.items():
        ax_rmse.semilogy([p[0] for p in points], [p[1] for p in points], "o-", label=label)
    ax_rmse.set(xlabel="max_depth (-1: unbounded)", ylabel="RMSE against the same-depth reference",
                title="RMSE against depth")
    ax_rmse.legend(fontsize=8)
    for ax in (ax_share, ax_rmse):
        ax.grid(True, alpha=0.3)
    _save(fig, path)


def difference_limit(diff: np.ndarray) -> float:
    """The colour scale of a signed difference image: the 99th percentile of its magnitude."""
    return float(np.percentile(np.abs(diff), 99)) or 1e-6


def signed_colours(diff: np.ndarray) -> np.ndarray:
    """(H, W) signed difference -> (H, W, 3) RGB in [0, 1] on the RdBu_r map of `side_by_side`."""
    limit = difference_limit(diff)
    return plt.get_cmap("RdBu_r")(np.clip(diff / limit, -1, 1) * 0.5 + 0.5)[..., :3]


def side_by_side(image: np.ndarray, reference: np.ndarray, title: str, path: Path) -> None:
    """Tracer, reference, and their signed difference (mean over channels) as a diverging heat map."""
    diff = (image - reference).mean(axis=-1)
    limit = difference_limit(diff)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6))
    axes[0].imshow(srgb_encode(image))
    axes[0].set_title(title, fontsize=9)
    axes[1].imshow(srgb_encode(reference))
    axes[1].set_title("Mitsuba reference", fontsize=9)
    heat = axes[2].imshow(diff, cmap="RdBu_r", vmin=-limit, vmax=limit)
    axes[2].set_title("tracer - reference (mean of RGB)", fontsize=9)
    fig.colorbar(heat, ax=axes[2], fraction=0.046, pad=0.04)
    for ax in axes:
        ax.axis("off")
    _save(fig, path)


def performance_scaling(curves: dict[str, list], path: Path) -> None:
    """Render time against pixels, samples, depth and triangle count (log-log where it reads better)."""
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    ax = axes[0]
    x, y = zip(*curves["resolution"])
    ax.loglog(x, y, "o-")
    ax.set(xlabel="pixels", ylabel="render time [s]", title="path, 16 spp, max_depth 5")
    ax = axes[1]
    x, y = zip(*curves["spp"])
    ax.loglog(x, y, "o-")
    ax.set(xlabel="samples per pixel", title="path, 300 x 300, max_depth 5")
    ax = axes[2]
    labels = [("∞" if d < 0 else str(d)) for d, _ in curves["max_depth"]]
    ax.plot(labels, [t for _, t in curves["max_depth"]], "o-")
    ax.set(xlabel="max_depth", title="path, 300 x 300, 16 spp")
    ax = axes[3]
    for kind in ("bvh", "brute force", "Mitsuba"):
        pts = [(n, t) for k, n, t in curves["triangles"] if k == kind]
        if pts:
            ax.loglog(*zip(*pts), "o-", label=kind)
    ax.set(xlabel="triangles", title="path, 256 x 256, 16 spp, Cornell box")
    ax.legend(fontsize=8)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    _save(fig, path)


def scene_ratios(ratios: dict[str, float], path: Path) -> None:
    """The tracer's whole-process time over Mitsuba's per scene, a bar each (log scale), 1 marked."""
    names = list(ratios)
    fig, ax = plt.subplots(figsize=(8, 0.8 + 0.24 * len(names)))
    y = np.arange(len(names))
    values = [ratios[n] for n in names]
    ax.barh(y, values, color=["tab:green" if v < 1 else "tab:red" for v in values])
    ax.axvline(1.0, color="black", lw=1)
    ax.set_xscale("log")
    ax.set_yticks(y, names, fontsize=7)
    ax.invert_yaxis()
    ax.set(xlabel="tracer / Mitsuba, whole process (below 1: the tracer is faster)")
    ax.grid(True, axis="x", which="both", alpha=0.3)
    _save(fig, path)
