"""Path tracing: one path per sample, next-event estimation combined with BSDF sampling by MIS
(power heuristic), Russian roulette from `rr_depth`. Mitsuba's `path` integrator estimates the same
integral at the same `max_depth`.

Russian roulette survives with probability q = min(max(throughput) * eta^2, Q_MAX) and divides the
throughput by q, so a surviving path's weight stays at most 1 / eta^2 while its throughput is below
Q_MAX. Mitsuba caps q at 0.95, which lets weights grow as (rho / 0.95)^k in a scene of albedo rho > 0.95:
still unbiased, but the rare long paths that carry most of the light then come with huge weights and a
few hundred samples underestimate the image badly. Q_MAX < 1 keeps every path finite.
"""
from __future__ import annotations

import drjit as dr

from .. import compile_clock
from ..geometry import SceneGeometry
from ..materials import SurfaceBSDF
from ..materials.bsdf import DELTA, has_flag
from ..materials.flags import BSDFSample
from ..jit import INF, NO_PRIM, PCG32, Array2f, Array3f, Bool, Float, UInt32
from .direct import power_heuristic, sample_direct

Q_MAX = 0.9995  # largest Russian-roulette survival probability
TAIL_LANES = 1 << 14   # paths bounce by bounce go on in one kernel from this few on


class Strategies:
    """How many samples each strategy of direct lighting draws per vertex, as Mitsuba's `direct` integrator
    counts them (`emitter_samples`, `bsdf_samples`; the path tracer: one of each). The path draws one sample
    of each strategy used and weights it by the power heuristic over the strategies' sample fractions,
    w_light = (c_l p_l)^2 / ((c_l p_l)^2 + (c_b p_b)^2) (Veach 1997, eq. 9.13, c the fractions): the weights
    of a direction still sum to 1, so the expected image is that of the counts; only the noise differs. A
    strategy with no samples is not used: emitter sampling none (lights are found by BSDF sampling alone,
    delta lights never), BSDF sampling none (light reaches a surface only through shadow rays: emitters seen
    after a bounce add nothing). A plain class: Dr.Jit's loops leave it alone (not a struct of their state)."""

    def __init__(self, emitter: int = 1, bsdf: int = 1):
        self.emitter, self.bsdf = emitter, bsdf

    def __repr__(self) -> str:
        return f"Strategies(emitter={self.emitter}, bsdf={self.bsdf})"

    @property
    def fractions(self) -> tuple[float, float]:
        total = self.emitter + self.bsdf
        return self.emitter / total, self.bsdf / total


PATH = Strategies()


class PathState:
    """What a path carries from one vertex to the next (a Dr.Jit struct: the loop's state, by name).

    Directions: `d` is the direction of travel; at a vertex, wi = -d points away from the surface, back
    along the ray the light leaves by (geometry.emitted and the BSDFs take wi)."""
    DRJIT_STRUCT = {"L": Array3f, "beta": Array3f, "eta": Float, "o": Array3f, "d": Array3f, "t_min": Float,
                    "t_max": Float, "skip": UInt32, "prev_delta": Bool, "prev_pdf": Float, "rays": UInt32,
                    "depth": UInt32, "active": Bool}

    def __init__(self, o=None, d=None, t_min=None, t_max=None, active=None):
        self.L, self.beta, self.eta = Array3f(0.0), Array3f(1.0), Float(1.0)   # radiance, throughput, IOR ratio
        self.o, self.d, self.t_min, self.t_max = o, d, t_min, t_max            # the next ray
        self.skip = UInt32(NO_PRIM)          # the primitive the ray leaves (not hit again)
        self.prev_delta = Bool(True)         # the last vertex was specular (or the camera): no MIS on emission
        self.prev_pdf = Float(0.0)           # solid-angle pdf of the last BSDF sample, for MIS
        self.rays, self.depth, self.active = UInt32(0), UInt32(0), active


def path_radiance(geo: SceneGeometry, o: Array3f, d: Array3f, t_min: Float, t_max: Float, rng: PCG32,
                  max_depth: UInt32, rr_depth: UInt32, strategies: Strategies = PATH,
                  hide: str | None = None) -> tuple[Array3f, UInt32]:
    """Radiance along each camera ray and the number of rays each path traced. With a mesh BVH the paths go
    bounce by bounce (_wavefront, where SceneGeometry.bounce_by_bounce), else in one kernel
    (_megakernel); each lane's path is the same. `strategies`: the samples of each strategy of direct
    lighting (Mitsuba's `direct` integrator is this path tracer at max_depth 2 with its own counts).
    `hide`: the integrator's hide_emitters (Scene.hide_emitters): no emission reaches the camera directly,
    and with "pass" camera rays go on through emitting shapes (Mitsuba 3.9.1's path.cpp and direct.cpp:
    skip_area_emitters), their depth unchanged."""
    path = PathState(o, d, t_min, t_max, Bool(max_depth > 0))
    return trace_paths(geo, rng, path, _bounce, max_depth, rr_depth, strategies, hide)


def trace_paths(geo: SceneGeometry, rng: PCG32, path, bounce, *args) -> tuple[Array3f, UInt32]:
    """Runs bounce(geo, rng, path, *args) until no lane of `path` (a Dr.Jit struct with `L`, `rays` and
    `active`) is active; returns its L and rays. With a mesh BVH the paths go bounce by bounce (_wavefront, where
    SceneGeometry.bounce_by_bounce), else in one kernel (_megakernel); each lane's path is the same."""
    trace = _wavefront if geo.bounce_by_bounce else _megakernel
    return trace(geo, rng, path, bounce, *args)


def _megakernel(geo: SceneGeometry, rng: PCG32, path, bounce, *args) -> tuple[Array3f, UInt32]:
    """Every path to its end in the caller's kernel, its vertices in a symbolic loop (dr.while_loop written
    out: dr.syntax would read and rewrite this module's source at each process's import)."""
    def body(path, rng):
        bounce(geo, rng, path, *args)
        return path, rng

    path, rng = dr.while_loop((path, rng), lambda path, rng: path.active, body, labels=("path", "rng"))
    return path.L, path.rays


def _wavefront(geo: SceneGeometry, rng: PCG32, path, bounce, *args) -> tuple[Array3f, UInt32]:
    """The paths one bounce per step, the state of those still going evaluated between steps, and their
    ray queries batched (SceneGeometry.batched): a packet of lanes then never waits in a BVH walk for
    its slowest ray (wherever a path ends its L and rays go out). Once at most TAIL_LANES paths are left they
    go on in one kernel (_megakernel): a batched bounce costs its launches and the tracing of its kernels
    however few its paths, and with max_depth -1 the last few paths take tens of bounces."""
    n = dr.width(path.o)
    for name in type(path).DRJIT_STRUCT:       # one value per lane, to gather from
        value = getattr(path, name)
        setattr(path, name, value if dr.width(value) == n else dr.tile(value, n))
    L, rays, lane = dr.zeros(Array3f, n), dr.zeros(UInt32, n), dr.arange(UInt32, n)
    with geo.batched():
        while True:
            going = dr.compress(path.active)
            if dr.width(going) == 0:
                return L, rays
            if dr.width(going) < dr.width(lane):
                path, rng, lane = (dr.gather(type(x), x, going) for x in (path, rng, lane))
            if dr.width(going) <= TAIL_LANES:
                break
            bounce(geo, rng, path, *args)
            ended = ~path.active
            dr.scatter(L, path.L, lane, ended)
            dr.scatter(rays, path.rays, lane, ended)
            dr.eval(path, rng, L, rays)
            compile_clock.lap()    # a bounce's thousands of walk kernels leave Dr.Jit's history
    tail_L, tail_rays = _megakernel(geo, rng, path, bounce, *args)
    dr.scatter(L, tail_L, lane)
    dr.scatter(rays, tail_rays, lane)
    return L, rays


def _bounce(geo, rng, path: PathState, max_depth, rr_depth, strategies: Strategies = PATH,
            hide: str | None = None) -> None:
    """A path's next vertex (_vertex), then Russian roulette."""
    active_next, passed = _vertex(geo, rng, path, max_depth, strategies, hide)
    path.t_min, path.t_max = Float(0.0), Float(INF)
    path.depth = dr.select(passed, path.depth, path.depth + 1)
    rr_active = path.depth >= rr_depth
    q = dr.minimum(dr.max(path.beta) * path.eta * path.eta, Q_MAX)
    survive = rng.next_float32() < q
    path.beta = dr.select(rr_active, path.beta / q, path.beta)
    path.active = active_next & (~rr_active | survive) & (dr.max(path.beta) > 0)


def _vertex(geo, rng, path: PathState, max_depth, strategies: Strategies, hide: str | None) -> tuple[Bool, Bool]:
    """One path vertex: emission (MIS-weighted), a shadow ray weighted by the BSDF (MIS-weighted against
    sampling the BSDF, where it has a non-delta lobe), and the next direction sampled from the BSDF,
    updating `path`; returns whether the path may go on, and whether its camera ray passed through an
    emitting shape (`hide` "pass": not a vertex)."""
    L, beta, d, rays, depth = path.L, path.beta, path.d, path.rays, path.depth
    hit = geo.closest_hit(path.o, d, path.t_min, path.t_max, path.skip)
    rays += 1
    surf = geo.surface(hit)
    wi = -d
    c_light, c_bsdf = strategies.fractions
    if geo.has_lights:
        cos_l = dr.abs(dr.dot(surf.ns, d))
        le = geo.emitted(surf, wi)
        on_light = dr.max(le) > 0
        pdf_light = geo.light_pdf_area(surf) * dr.square(dr.select(on_light, hit.t, 0.0)) / dr.maximum(cos_l, 1e-30)
        if geo.has_environment:              # a ray that hits nothing sees the environment
            pdf_light = dr.select(surf.valid, pdf_light, geo.environment_pdf(d))
        w = dr.select(path.prev_delta, 1.0, power_heuristic(path.prev_pdf * c_bsdf, pdf_light * c_light))
        if not strategies.bsdf:          # only the camera's rays find emitters: no BSDF-sampled light
            w = dr.select(depth == 0, 1.0, 0.0)
        if hide:                         # hide_emitters: none seen directly
            w = dr.select(depth == 0, 0.0, w)
        L += dr.select(on_light, beta * le * w, Array3f(0.0))
    active_next = surf.valid & (depth + 1 < max_depth)
    passed = (depth == 0) & geo.emits(surf) if hide == "pass" else Bool(False)
    going_on = active_next                  # passing an emitting shape goes on
    active_next = active_next & ~passed     # a new array: going_on keeps its own
    if geo.batch:               # its ray queries launch kernels of their own (a wavefront): no symbolic branch
        L, rays, bs, weight = _scatter(geo, rng, surf, wi, beta, L, rays, active_next, strategies)
    else:                       # a path's last vertex scatters nothing: a packet of such lanes skips the work
        L, rays, bs, weight, rng.state = dr.if_stmt(
            (L, rays, rng.state), going_on,
            lambda L, rays, state: _scatter(geo, PCG32(rng), surf, wi, beta, L, rays, active_next, strategies,
                                            state),
            lambda L, rays, state: (L, rays, BSDFSample(Array3f(0.0), Float(0.0), Float(1.0), UInt32(0)),
                                    Array3f(0.0), state),
            label="scatter")
    path.L, path.rays = L, rays
    path.beta, path.eta = dr.select(passed, beta, beta * weight), dr.select(passed, path.eta, path.eta * bs.eta)
    path.o, path.d, path.skip = surf.p, dr.select(passed, d, bs.wo), surf.prim
    path.prev_delta, path.prev_pdf = passed | has_flag(bs.sampled_type, DELTA), bs.pdf
    return going_on, passed


def _scatter(geo, rng, surf, wi: Array3f, beta: Array3f, L: Array3f, rays: UInt32, active: Bool,
             strategies: Strategies, state=None):
    """Where `active`: the shadow ray (MIS-weighted) added to L and counted in rays, and the next direction
    sampled from the BSDF; returns L, rays, the BSDF sample and its weight. Given `state` (as a branch of
    dr.if_stmt, on a copy of rng): rng draws from that state, and its state after the draws is returned too."""
    if state is not None:
        rng.state = state
    c_light, c_bsdf = strategies.fractions
    bsdf = SurfaceBSDF(geo.materials, surf, wi, active)
    if geo.has_lights and strategies.emitter:
        nee = active & bsdf.smooth & bsdf.lit
        geo.keep(L, nee, active, rng, bsdf.state())
        ds = sample_direct(geo, surf, bsdf, rng.next_float32(), rng.next_float32(), rng.next_float32(), nee)
        L += dr.select(nee, beta * ds.value * power_heuristic(ds.pdf_light * c_light, ds.pdf_bsdf * c_bsdf),
                       Array3f(0.0))
        rays += dr.select(nee, 1, 0)
    u1 = rng.next_float32()
    bs, weight = bsdf.sample(u1, Array2f(rng.next_float32(), rng.next_float32()), active)
    return (L, rays, bs, weight) if state is None else (L, rays, bs, weight, rng.state)
