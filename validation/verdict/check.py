"""`validate check`: is a renderer right on a scene? A verdict a CI can act on.

For each scene, estimator and depth: the renderer under test renders `passes` independent passes; Mitsuba
renders the same number of passes at the same samples per pass (an equal-budget reference, cached by the
scene's content); `stats.compare` decides `agree`, `disagree` or `inconclusive` (with a margin:
`equivalent`, `disagree` or `inconclusive`). An undecided comparison (a rejection only in blocks decided by
a few rare samples; with a margin, equivalence not yet shown) is repeated on fresh passes, in at most three
stages up to `max_spp`, each at level alpha / stages. With a margin the check plans its own budget: the
first stage measures the variances, and the second is sized from them so that an unbiased renderer would be
shown equivalent with probability POWER (`next_spp`). What is still inconclusive then says what would settle
it. Every refusal (`prepare`) comes before the first pass.

The branching (report) estimator traces many rays per camera ray: its reference has REPORT_REFERENCE_SPP
times its camera rays per pass. Where few camera rays see a small bright feature, a side's pass means are
skewed by how few they are; with 32 Mitsuba samples per camera ray the branching estimator's passes were
far more skewed than Mitsuba's, and the comparison disagreed on correct renders more often than alpha. Of
8, 16 and 32 samples per camera ray, 8 makes the two sides skewed most alike (reports/calibration.md
measures the comparison at it).
"""
from __future__ import annotations

import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import protocol
from .references import Reference, mitsuba_reference
from .renderers import ExternalRenderer, TracerRenderer, independence
from .scenefile import ScenePlan, ScenePlanError, plan
from .stats import POWER, Comparison, Margin, block_means, compare

REPORT_REFERENCE_SPP = 8    # Mitsuba samples per pass per camera ray of the branching estimator
EXIT_CODES = {"agree": 0, "equivalent": 0, "disagree": 1, "inconclusive": 3}
EXIT_USAGE = 2
EXIT_INCOMPLETE = 4     # a check was stopped (--timeout) and none disagrees: the run is incomplete


@dataclass(frozen=True)
class Settings:
    passes: int = protocol.PASSES
    spp: int | None = None          # per pass; None: protocol.SPP (branching estimator: protocol.REPORT_SPP)
    seed: int = protocol.SEED_TEST
    alpha: float = protocol.ALPHA
    size: int | None = protocol.SIZE
    max_spp: int = protocol.MAX_SPP
    margin: Margin | None = None    # None: a test of difference only (agree / disagree / inconclusive)

    def __post_init__(self):
        for name, low in (("passes", 3), ("spp", 1), ("size", 4), ("max_spp", 1)):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < low):
                raise ScenePlanError(f"{name} must be an integer of at least {low}, got {value!r}")
        if not 0 < self.alpha < 1:
            raise ScenePlanError(f"alpha must lie strictly between 0 and 1, got {self.alpha}")
        if not 0 <= self.seed < 2**31:
            raise ScenePlanError(f"seed must lie in [0, 2^31), got {self.seed}")


@dataclass
class CheckResult:
    scene: str
    renderer: str
    max_depth: int
    verdict: str
    spp: int                   # samples per pass of the renderer under test, after any escalation
    reference_spp: int         # Mitsuba's samples per pass
    passes: int
    seconds: float             # rendering and testing, reference included unless cached
    width: int
    height: int
    comparison: Comparison = field(repr=False)
    note: str = ""
    alpha: float = protocol.ALPHA   # the check's family-wise level, spent over its stages
    stage: int = 1                  # the stage that decided (or the last run)
    stages: int = 1                 # the stages planned (spp to max_spp), each at level alpha / stages
    spent_spp: int = 0              # samples per pixel each side rendered over all stages (passes x spp summed)

    def line(self) -> str:
        c = self.comparison
        r, col, ch = c.worst_block
        margin = (f", margin {_pct(c.margin.image)} image mean, {_pct(c.margin.block)} block" if c.margin else "")
        return (f"{self.verdict:<12} {self.scene} [{self.renderer}, max_depth {self.max_depth}]: "
                f"{c.rejected}/{c.tests + 3} tests rejected"
                f"{f' (+{c.untrusted_rejected} decided by rare samples)' if c.untrusted_rejected else ''}, "
                f"worst block ({r}, {col}) {'RGB'[ch]} p = {c.min_p:.2g}, image mean {c.relative_mean_difference:+.2%}; "
                f"{c.detectable()}{margin}; "
                f"{self.passes} x {self.spp} spp vs Mitsuba {self.passes} x {self.reference_spp} spp"
                f"{f' (stage {self.stage} of {self.stages}, {self.spent_spp} spp in all)' if self.stages > 1 else ''}, "
                f"{self.width} x {self.height}, {self.seconds:.1f} s" + (f"; {self.note}" if self.note else ""))

    def as_dict(self) -> dict:
        c = self.comparison
        out = {"scene": self.scene, "renderer": self.renderer, "max_depth": self.max_depth,
               "verdict": self.verdict, "spp": self.spp, "reference_spp": self.reference_spp,
               "passes": self.passes, "width": self.width, "height": self.height, "seconds": self.seconds,
               "alpha": self.alpha, "stage": self.stage, "stages": self.stages, "stage_alpha": c.alpha,
               "spent_spp": self.spent_spp, "tests": c.tests, "rejected": c.rejected,
               "rejected_rare": c.untrusted_rejected, "min_p": c.min_p, "worst_block": list(c.worst_block),
               "worst_t": c.worst_t, "mean": c.mean_test, "reference_mean": c.mean_reference,
               "relative_mean_difference": c.relative_mean_difference,
               "detectable_bias": {"power": POWER, "image_mean": [float(x) for x in c.detectable_image],
                                   "median_block": c.detectable_block}, "note": self.note}
        if c.margin is not None:
            out["equivalence"] = {"margin_image": c.margin.image, "margin_block": c.margin.block,
                                  "image_means": [bool(x) for x in c.equivalent_image],
                                  "blocks": int(c.equivalent_map.sum()), "spp_factor_needed": c.needed,
                                  "spp_factor_unbiased": c.needed_unbiased}
        return out


@dataclass
class Skipped:
    """A check the renderer declined: the scene uses something it does not render (its exit status
    renderers.EXIT_UNSUPPORTED, or a built-in adapter's refusal)."""
    scene: str
    renderer: str
    max_depth: int | None       # None: the scene's own (refused before it was planned)
    reason: str

    def line(self) -> str:
        depth = "the scene's max_depth" if self.max_depth is None else f"max_depth {self.max_depth}"
        return f"{'skipped':<12} {self.scene} [{self.renderer}, {depth}]: unsupported: {self.reason}"

    def as_dict(self) -> dict:
        return {"scene": self.scene, "renderer": self.renderer, "max_depth": self.max_depth,
                "verdict": "skipped: unsupported", "note": self.reason}


@dataclass
class TimedOut:
    """A check stopped because a call of the renderer under test outlived --timeout: no verdict; the run goes
    on with the next check."""
    scene: str
    renderer: str
    max_depth: int
    reason: str
    seconds: float

    def line(self) -> str:
        return (f"{'timed out':<12} {self.scene} [{self.renderer}, max_depth {self.max_depth}]: no verdict: "
                f"{self.reason}, {self.seconds:.1f} s")

    def as_dict(self) -> dict:
        return {"scene": self.scene, "renderer": self.renderer, "max_depth": self.max_depth,
                "verdict": "timed out", "note": self.reason, "seconds": self.seconds}


def _pct(x: float) -> str:
    return f"{100 * x:g}%"


def _branching(renderer) -> bool:
    return isinstance(renderer, TracerRenderer) and renderer.estimator == "report"


def reference_spp(renderer, spp: int) -> int:
    """Mitsuba's samples per pass against `spp` of `renderer` (equal, or per camera ray of the branching one)."""
    return spp * REPORT_REFERENCE_SPP if _branching(renderer) else spp


def default_spp(renderer) -> int:
    return protocol.REPORT_SPP if _branching(renderer) else protocol.SPP


def stages(spp: int, max_spp: int) -> list[int]:
    """The samples per pass of a test of difference's stages: spp, the geometric mean of spp and max_spp, and
    max_spp (fewer where they coincide); a check runs at most as many stages, each at level alpha / their number."""
    if max_spp <= spp:
        return [spp]
    return sorted({spp, round((spp * max_spp) ** 0.5), max_spp})


def next_spp(c: Comparison, spp: int, stage: int, max_spp: int) -> int | None:
    """With a margin, the samples per pass of the stage after an undecided one (None: no stage can decide it):
    the second stage is sized from the first's standard errors for an unbiased renderer, a later one for the
    difference its predecessor measured (stats.spp_factor: every TOST passes with probability POWER), at least
    `spp` and at most `max_spp`; a stage that would need more than `max_spp` runs at `max_spp`, once."""
    factor = c.needed_unbiased if stage == 1 else c.needed
    if not np.isfinite(factor):
        return None
    want = _round_up(spp * factor)
    if want > max_spp and spp >= max_spp:
        return None
    return min(max(want, spp), max_spp)


def check(scene_file: str | Path, renderer: TracerRenderer | ExternalRenderer, max_depth: int | None = None,
          defines: dict[str, str] | None = None, settings: Settings = Settings(),
          output: Path | None = None) -> CheckResult:
    """The verdict on one scene, renderer and depth (see the module's docstring). With `output`, a
    disagreeing or inconclusive check writes its images there (ours, reference, difference, blocks)."""
    scene_plan = prepare(scene_file, renderer, max_depth, defines, settings)
    return run(scene_plan, renderer, settings, output)


def prepare(scene_file: str | Path, renderer: TracerRenderer | ExternalRenderer, max_depth: int | None = None,
            defines: dict[str, str] | None = None, settings: Settings = Settings()) -> ScenePlan:
    """The scene planned and every refusal of it made before anything renders: the scene as both renderers
    will read it, the options, and the external renderer's command for the first pass."""
    scene_plan = plan(scene_file, defines, settings.size, max_depth)
    if _branching(renderer) and scene_plan.max_depth < 0:
        raise ScenePlanError("the branching (report) estimator needs a finite max_depth (--max-depth or "
                             "--report-depth)")
    scene_plan.mitsuba_xml()                        # Mitsuba's side: refuses an integrator it cannot compare
    if isinstance(renderer, TracerRenderer):
        scene_plan.tracer_scene()                   # the tracer's loader refuses what it does not honour
    else:
        renderer.prepare(scene_plan, settings.spp or default_spp(renderer), settings.seed)
    return scene_plan


@dataclass
class Sequence:
    """How a staged comparison ended: the deciding (or last) stage's comparison, that stage, the stages planned,
    its samples per pass and the samples per pass summed over the stages run."""
    comparison: Comparison
    stage: int
    stages: int
    spp: int
    spent: int


def sequential(decide: Callable[[int, int, float], Comparison], spp: int, max_spp: int, alpha: float,
               margin: Margin | None) -> Sequence:
    """The stages of a check: `decide(stage, spp, level)` compares fresh passes of both sides at `spp` samples
    per pass and `level`. Each stage runs at alpha / stages (a Bonferroni spending of the level over the stages
    planned: the family-wise error rates hold whichever stage decides, and however a stage's samples were
    chosen from the stages before it). Without a margin, only an inconclusive verdict (a rejection resting on
    rare samples) goes on, at the samples per pass of `stages`; with one, any verdict but equivalent or
    disagree, at the samples per pass `next_spp` plans from the stage before."""
    ladder = stages(spp, max_spp)
    level, spent = alpha / len(ladder), 0
    for stage in range(1, len(ladder) + 1):
        c = decide(stage, spp, level)
        spent += spp
        if c.verdict != "inconclusive" or stage == len(ladder):
            break
        following = ladder[stage] if margin is None else next_spp(c, spp, stage, max_spp)
        if following is None:
            break
        spp = following
    return Sequence(c, stage, len(ladder), spp, spent)


def run(scene_plan: ScenePlan, renderer: TracerRenderer | ExternalRenderer, settings: Settings = Settings(),
        output: Path | None = None) -> CheckResult:
    """Renders and decides a prepared check, stage by stage (`sequential`), each on fresh passes of both sides."""
    rendered = {}

    def decide(stage: int, spp: int, level: float) -> Comparison:
        offset = (stage - 1) * settings.passes     # fresh seeds on both sides
        rendered["ref"] = mitsuba_reference(scene_plan, settings.passes, reference_spp(renderer, spp),
                                            seed=protocol.SEED_REFERENCE + offset)     # Mitsuba refuses first
        rendered["ours"] = renderer.passes(scene_plan, settings.passes, spp, settings.seed + offset)
        independence(rendered["ours"], noisy=bool((rendered["ref"].var > 0).any()))   # identical or correlated: refused
        return compare(block_means(rendered["ours"], protocol.BLOCK), rendered["ref"].blocks, level, settings.margin)

    start = time.perf_counter()
    seq = sequential(decide, settings.spp or default_spp(renderer), settings.max_spp, settings.alpha, settings.margin)
    c, ours = seq.comparison, rendered["ours"]
    label = renderer.label_for(scene_plan) if isinstance(renderer, TracerRenderer) else renderer.label
    result = CheckResult(str(scene_plan.path), label, scene_plan.max_depth, c.verdict, seq.spp,
                         reference_spp(renderer, seq.spp), settings.passes, time.perf_counter() - start,
                         scene_plan.width, scene_plan.height, c, _note(c, seq.spp, settings, ours),
                         settings.alpha, seq.stage, seq.stages, settings.passes * seq.spent)
    if output is not None and result.verdict not in ("agree", "equivalent"):
        write_images(output, scene_plan, result, ours.mean(0), rendered["ref"])
    return result


def _note(c: Comparison, spp: int, settings: Settings, ours: np.ndarray) -> str:
    if c.verdict == "inconclusive" and c.margin is not None and not c.rejected:
        if not np.isfinite(c.needed):
            return ("a measured difference lies at or beyond its margin without being significant; more samples "
                    f"per pass than {spp} would decide it")
        need = _round_up(spp * c.needed)
        return (f"not shown within the margin at {spp} spp per pass: about {need} would decide it"
                + (f" (--max-spp {need})" if need > settings.max_spp else ""))
    if c.verdict == "inconclusive":
        return (f"the rejected blocks are decided by a few rare samples; settle it with more than {spp} spp "
                f"per pass (--spp {spp * 4} or --max-spp {max(spp * 4, settings.max_spp * 4)})")
    if c.verdict == "equivalent" and c.rejected:
        return "a difference was detected, within the margin"
    if c.mean_reference == 0 and not ours.any():
        return "both images are black"
    return ""


def _round_up(spp: float) -> int:
    """spp rounded up to two significant digits."""
    digits = max(0, len(str(int(spp))) - 2)
    return int(-(-spp // 10 ** digits) * 10 ** digits)


def write_images(folder: Path, scene_plan: ScenePlan, result: CheckResult, ours: np.ndarray, ref: Reference) -> None:
    """ours.exr/png, reference.exr/png, difference.png (red: ours brighter), blocks.png (rejected blocks:
    red, rejected but decided by rare samples: orange, else grey by -log10 p), and index.html: the images as
    data in the interactive viewer (validation.viewer) with the block test's p-values."""
    from tracer.imageio import write_exr, write_png

    from ..reports.plots import signed_colours
    from ..viewer import BlockTest, write_viewer

    folder = Path(folder) / f"{scene_plan.path.stem}-d{result.max_depth}-{_slug(result.renderer)}"
    folder.mkdir(parents=True, exist_ok=True)
    write_exr(folder / "ours.exr", ours)
    write_exr(folder / "reference.exr", ref.mean)
    write_png(folder / "ours.png", ours)
    write_png(folder / "reference.png", ref.mean)
    _write_rgb8(folder / "difference.png", signed_colours((ours - ref.mean).mean(-1)))
    _write_rgb8(folder / "blocks.png", _block_map(result.comparison, scene_plan))
    c = result.comparison
    rows, cols = c.p.shape[0] * protocol.BLOCK, c.p.shape[1] * protocol.BLOCK   # the blocks' pixels
    write_viewer(folder, f"{scene_plan.path.name}: {result.renderer} against Mitsuba",
                 {"ours": ours[:rows, :cols], "Mitsuba": ref.mean[:rows, :cols]}, compare=("ours", "Mitsuba"),
                 block_test=BlockTest(c.p, c.alpha / 2 / c.tests, "Welch's t-test per 4 x 4 block (Bonferroni)"),
                 verdicts=[f"`{result.line()}`"] + ([result.note] if result.note else []),
                 provenance={"scene": str(scene_plan.path), "command": " ".join(sys.argv)})


def _block_map(c: Comparison, scene_plan: ScenePlan) -> np.ndarray:
    shade = np.clip(-np.log10(np.maximum(c.p.min(-1), 1e-300)) / -np.log10(c.alpha / c.tests), 0, 1)
    rgb = np.repeat((0.15 + 0.6 * shade)[..., None], 3, axis=-1)
    rgb[(c.rejected_map & ~c.trusted).any(-1)] = (1.0, 0.6, 0.0)
    rgb[(c.rejected_map & c.trusted).any(-1)] = (0.9, 0.1, 0.1)
    big = np.kron(rgb, np.ones((protocol.BLOCK, protocol.BLOCK, 1)))
    out = np.zeros((scene_plan.height, scene_plan.width, 3))
    out[:big.shape[0], :big.shape[1]] = big
    return out


def _write_rgb8(path: Path, rgb: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8), "RGB").save(path)


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in text).strip("-")[:40]


def exit_code(results: list[CheckResult], timed_out: list[TimedOut] = ()) -> int:
    """1 if a check disagrees; else EXIT_INCOMPLETE if one timed out; else 3 if one is inconclusive; else 0."""
    verdicts = {r.verdict for r in results}
    return (1 if "disagree" in verdicts else EXIT_INCOMPLETE if timed_out else 3 if "inconclusive" in verdicts
            else 0)


def write_json(results: list[CheckResult], path: Path, skipped: list[Skipped] = (),
               timed_out: list[TimedOut] = ()) -> None:
    from ..reports.provenance import write_json as write

    write(path, {"exit_code": exit_code(results, timed_out), "checks": [r.as_dict() for r in results],
                 "skipped": [s.as_dict() for s in skipped], "timed_out": [t.as_dict() for t in timed_out]})


def _properties(r: CheckResult) -> dict[str, str]:
    """A JUnit test case's properties: the verdict, the bias it could have missed, the margin, the budget."""
    c = r.comparison
    out = {"verdict": r.verdict, "detectable_bias_image_mean_rgb": " ".join(f"{x:.4g}" for x in c.detectable_image),
           "detectable_bias_median_block": f"{c.detectable_block:.4g}", "power": f"{POWER:g}", "alpha": f"{r.alpha:g}",
           "spp_per_pass": str(r.spp), "passes": str(r.passes), "stage": f"{r.stage}/{r.stages}"}
    if c.margin is not None:
        out |= {"margin_image": f"{c.margin.image:g}", "margin_block": f"{c.margin.block:g}"}
    return out


def write_junit(results: list[CheckResult], path: Path, skipped: list[Skipped] = (),
                timed_out: list[TimedOut] = ()) -> None:
    """JUnit XML: one test case per scene x renderer x depth; disagree is a failure, a timed-out check an error,
    inconclusive and unsupported skipped; each case's properties carry the detectable bias and the margin."""
    suite = ET.Element("testsuite", name="validate check", tests=str(len(results) + len(skipped) + len(timed_out)),
                       failures=str(sum(r.verdict == "disagree" for r in results)), errors=str(len(timed_out)),
                       skipped=str(sum(r.verdict == "inconclusive" for r in results) + len(skipped)),
                       time=f"{sum(r.seconds for r in [*results, *timed_out]):.3f}")
    for r in results:
        case = ET.SubElement(suite, "testcase", classname=f"validate.check.{Path(r.scene).stem}",
                             name=f"{r.renderer} max_depth={r.max_depth}", time=f"{r.seconds:.3f}")
        properties = ET.SubElement(case, "properties")     # first, as pytest writes them
        for name, value in _properties(r).items():
            ET.SubElement(properties, "property", name=name, value=value)
        if r.verdict == "disagree":
            ET.SubElement(case, "failure", message=r.comparison.summary()).text = r.line()
        elif r.verdict == "inconclusive":
            ET.SubElement(case, "skipped", message=r.note or r.comparison.summary())
        ET.SubElement(case, "system-out").text = r.line()
    for r in skipped:
        case = ET.SubElement(suite, "testcase", classname=f"validate.check.{Path(r.scene).stem}",
                             name=f"{r.renderer} max_depth={r.max_depth}", time="0")
        ET.SubElement(case, "skipped", message=f"unsupported: {r.reason}")
    for r in timed_out:
        case = ET.SubElement(suite, "testcase", classname=f"validate.check.{Path(r.scene).stem}",
                             name=f"{r.renderer} max_depth={r.max_depth}", time=f"{r.seconds:.3f}")
        ET.SubElement(case, "error", message=f"timed out: {r.reason}").text = r.line()
    root = ET.Element("testsuites")
    root.append(suite)
    from ..reports.provenance import write_text

    write_text(path, "<?xml version='1.0' encoding='utf-8'?>\n" + ET.tostring(root, encoding="unicode") + "\n")
