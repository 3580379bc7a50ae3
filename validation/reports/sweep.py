"""Timed runs of the tracer's estimators and of Mitsuba's `path`, measured against a reference.

A run is one (estimator, max_depth, spp, size, N, M) setting rendered as `passes` independent images;
its row holds the time per image (compile time apart from render time), the error metrics of one
image averaged over the passes, and Welch's test of the passes against the reference when passes >= 2.
Rows are appended to a CSV file as each run finishes, with a digest of the scene's content (the file and
every file it names); a sweep that is started again skips the runs already there for the same content, so
an interrupted sweep resumes where it stopped and an edited scene is rendered again.
"""
from __future__ import annotations

import csv
import dataclasses
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..verdict.check import REPORT_REFERENCE_SPP
from ..verdict.metrics import measure
from ..verdict.mitsuba_render import mitsuba
from ..verdict.protocol import ALPHA, BLOCK
from .provenance import write_json
from ..verdict.references import Reference, mitsuba_reference
from ..verdict.renderers import TracerRenderer
from ..verdict.scenefile import files_digest, plan
from ..verdict.stats import block_means, compare

ESTIMATORS = ("path", "report", "mitsuba")   # the tracer's two estimators and Mitsuba's `path` as a peer
IMAGES = Path(".cache/runs")                # first image of every run, for the report's image panels


@dataclass(frozen=True)
class RunSpec:
    estimator: str
    max_depth: int          # Mitsuba's max_depth; the report's depth D is max_depth D + 2
    spp: int
    size: int
    passes: int = 1
    direct: int = 0         # N (report estimator only)
    indirect: int = 0       # M (report estimator only)
    seed: int = 1

    @property
    def key(self) -> str:
        return (f"{self.estimator}-d{self.max_depth}-spp{self.spp}-{self.size}px-x{self.passes}"
                f"-N{self.direct}-M{self.indirect}-s{self.seed}")

    @property
    def label(self) -> str:
        if self.estimator == "report":
            return f"tracer report (N={self.direct}, M={self.indirect})"
        return "Mitsuba path" if self.estimator == "mitsuba" else "tracer path"


FIELDS = [f.name for f in dataclasses.fields(RunSpec)] + [
    "key", "seconds", "compile_seconds", "render_seconds", "rays", "rmse", "rel_mse", "ssim",
    "bias_r", "bias_g", "bias_b", "test", "rejected", "min_p", "content"]


def _tracer_images(scene_file: Path, spec: RunSpec) -> tuple[list[np.ndarray], list[float], list[float], int]:
    renderer = (TracerRenderer("report", spec.direct, spec.indirect) if spec.estimator == "report"
                else TracerRenderer(spec.estimator))
    results = renderer.results(_plan(scene_file, spec), spec.passes, spec.spp, spec.seed * 1000)
    return ([r.image for r in results], [r.render_seconds for r in results], [r.compile_seconds for r in results],
            sum(r.rays for r in results) // spec.passes)


def _mitsuba_images(scene_file: Path, spec: RunSpec) -> tuple[list[np.ndarray], list[float], list[float], int]:
    """Mitsuba's passes; a warm-up render first, whose extra time over a timed render is its compile time."""
    mi = mitsuba()
    scene = _plan(scene_file, spec).mitsuba_scene(spec.spp)

    def timed(seed: int) -> tuple[np.ndarray, float]:
        start = time.perf_counter()
        image = np.array(mi.render(scene, seed=seed, spp=spec.spp), dtype=np.float32)[..., :3]
        return image, time.perf_counter() - start

    _, warmup = timed(2**31 - spec.seed)
    images, seconds = zip(*(timed(spec.seed * 1000 + k) for k in range(spec.passes)))
    render_s = float(np.mean(seconds))
    return list(images), list(seconds), [max(warmup - render_s, 0.0)] * spec.passes, 0


def _plan(scene_file: Path, spec: RunSpec):
    return plan(scene_file, {"width": str(spec.size), "height": str(spec.size)}, max_depth=spec.max_depth)


def execute(scene_file: Path, spec: RunSpec, ref: Reference) -> tuple[dict, np.ndarray]:
    """Renders `spec`, measures it against `ref`; returns its row and its first image."""
    run = _mitsuba_images if spec.estimator == "mitsuba" else _tracer_images
    images, renders, compiles, rays = run(scene_file, spec)
    metrics = [measure(im, ref) for im in images]
    row = dataclasses.asdict(spec) | {
        "key": spec.key, "render_seconds": float(np.mean(renders)), "compile_seconds": float(np.mean(compiles)),
        "rays": rays, "rmse": float(np.sqrt(np.mean([m.rmse ** 2 for m in metrics]))),
        "rel_mse": float(np.mean([m.rel_mse for m in metrics])), "ssim": float(np.mean([m.ssim for m in metrics])),
        **{f"bias_{c}": float(np.mean([m.bias[i] for m in metrics])) for i, c in enumerate("rgb")},
        "test": "", "rejected": "", "min_p": ""}
    row["seconds"] = row["render_seconds"] + row["compile_seconds"]
    if spec.passes >= 3:
        test = check_run(scene_file, spec, np.stack(images))
        row |= {"test": test.verdict, "rejected": test.rejected, "min_p": test.min_p}
    return row, images[0]


def check_run(scene_file: Path, spec: RunSpec, images: np.ndarray):
    """`validate check`'s test of a run's passes: against as many Mitsuba passes at the same samples per pass
    (the branching estimator: REPORT_REFERENCE_SPP per camera ray), cached."""
    spp = spec.spp * (REPORT_REFERENCE_SPP if spec.estimator == "report" else 1)
    ref = mitsuba_reference(_plan(scene_file, spec), spec.passes, spp)
    return compare(block_means(images, BLOCK), ref.blocks, ALPHA)


def read_rows(path: Path) -> list[dict]:
    """The finished runs in a results CSV (a torn last line from an interrupted write is ignored)."""
    if not path.exists():
        return []
    with path.open(newline="") as f:
        rows = [r for r in csv.DictReader(f) if None not in r and None not in r.values()]
    return [{k: _number(v) for k, v in r.items()} for r in rows]


def _number(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _append(path: Path, row: dict) -> None:
    if path.exists() and path.stat().st_size and path.open().readline().strip() != ",".join(FIELDS):
        path.replace(path.with_suffix(".old.csv"))   # another layout: kept aside, not appended to
    new = not path.exists() or path.stat().st_size == 0
    torn = not new and not path.read_bytes().endswith(b"\n")
    with path.open("a", newline="") as f:
        if torn:
            f.write("\n")   # end a line an interrupted write left unfinished; read_rows drops it
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        if new:
            writer.writeheader()
        writer.writerow(row)
        f.flush()
        os.fsync(f.fileno())


def image_path(scene_file: Path, spec: RunSpec) -> Path:
    return IMAGES / scene_file.stem / f"{spec.key}-{files_digest(scene_file)}.npy"


def sweep(scene_file: str | Path, specs: list[RunSpec], references, results: Path) -> list[dict]:
    """Runs every spec whose key is not yet in `results` (CSV) and appends its row; returns all rows.

    `references(max_depth, size)` gives the reference a spec is measured against.
    """
    scene_file = Path(scene_file)
    content = "sha256:" + files_digest(scene_file)
    done = {r["key"] for r in read_rows(results) if r.get("content") == content}
    todo = [s for s in dict.fromkeys(specs) if s.key not in done]
    results.parent.mkdir(parents=True, exist_ok=True)
    for spec in tqdm(todo, desc=f"{scene_file.stem}: runs", unit="run"):
        tqdm.write(f"  {spec.key}")
        row, image = execute(scene_file, spec, references(spec.max_depth, spec.size))
        row["content"] = content
        image_path(scene_file, spec).parent.mkdir(parents=True, exist_ok=True)
        np.save(image_path(scene_file, spec), image)
        _append(results, row)
    rows = list({r["key"]: r for r in read_rows(results) if r.get("content") == content}.values())
    write_json(results.with_suffix(".json"), rows)
    return rows
