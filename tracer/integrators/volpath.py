"""Mitsuba 3's `volpath`: volumetric path tracing with next-event estimation through media, as its
src/integrators/volpath.cpp estimates the radiative transfer equation (pbrt-v4 ch. 14; Novak et al. 2018).

Each path picks one colour channel uniformly; distances in a medium are sampled with that channel's
majorant (media.medium): free-flight sampling in a homogeneous medium, delta tracking in a heterogeneous
one, where a null collision continues the ray. Where the medium has a spectral (chromatic) extinction
(Mitsuba's has_spectral_extinction, on by default) the throughput is weighted by the ratio of the channels'
transmittance to the chosen channel's sampling density (tr / pdf, then sigma_n / P(null) at a null collision
and sigma_s / mean(sigma_t / majorant) at a real one); without it by the albedo sigma_s / sigma_t alone.

Next-event estimation from surfaces and medium scattering events sends a shadow ray that carries
transmittance (`transmittance`): ratio tracking through heterogeneous media (Novak et al. 2014), the
free-flight estimator through homogeneous ones, and surfaces with a null lobe (null, thindielectric, a mask)
pass it with their null transmission. Emitters found by BSDF or phase-function sampling are weighted
against it by MIS (power heuristic), the emitter's density measured from the last real scattering event;
null crossings are not path vertices: they neither count towards max_depth nor break a specular chain.
Russian roulette as in integrators.path (its Q_MAX), from depths above rr_depth as in volpath.cpp.

Mitsuba's `volpathmis` (volpathmis.cpp, `use_spectral_mis`; Miller, Georgiev and Jarosz 2019) weighs the
channels' distance sampling by the one-sample balance heuristic instead: a path sampled with channel c
contributes f / mean_k(p_k) rather than f / p_c, where p_k is the density of its distances (free flights,
collisions, shadow-ray passes) had channel k sampled them. The path carries r_k = p_k / p_c (`VolState.r`)
beside beta = f / p_c, so that f / mean_k(p_k) = beta / mean(r) (`_throughput`); Russian roulette reads that
throughput, the same whichever channel was drawn. Where the sampling densities do not differ by channel (a
grey extinction, or a heterogeneous medium's single majorant) r stays 1 and the two estimators are one
(up to rounding).
"""
from __future__ import annotations

import drjit as dr

from ..geometry import Hit, SceneGeometry
from ..jit import INF, NO_PRIM, PCG32, Array2f, Array3f, Bool, Float, UInt32
from ..materials import SurfaceBSDF
from ..materials.bsdf import DELTA, NULL, SMOOTH, has_flag
from ..media import VACUUM
from ..media.medium import channel_value
from .direct import light_direction, light_weight, power_heuristic
from .path import Q_MAX, trace_paths

SHADOW_EPSILON = 1e-3   # a shadow ray stops this fraction short of the light's point (Mitsuba's spawn_ray_to)


class VolState:
    """What a volumetric path carries from one step to the next (a Dr.Jit struct). A step is one
    collision: a real or null one in a medium, or a surface (null crossings included). The ray's
    surface hit is kept while null collisions move its origin towards it (hit_t shrinks)."""
    DRJIT_STRUCT = {"L": Array3f, "beta": Array3f, "eta": Float, "o": Array3f, "d": Array3f, "t_max": Float,
                    "skip": UInt32, "medium": UInt32, "channel": UInt32, "depth": UInt32, "active": Bool,
                    "specular": Bool, "last_p": Array3f, "last_pdf": Float, "needs_hit": Bool,
                    "hit_t": Float, "hit_prim": UInt32, "hit_b1": Float, "hit_b2": Float, "hit_p": Array3f,
                    "rays": UInt32, "r": Array3f}

    def __init__(self, o=None, d=None, t_max=None, medium=None, channel=None, active=None):
        self.L, self.beta, self.eta = Array3f(0.0), Array3f(1.0), Float(1.0)
        self.o, self.d, self.t_max, self.skip = o, d, t_max, UInt32(NO_PRIM)
        self.medium, self.channel, self.depth, self.active = medium, channel, UInt32(0), active
        self.specular = Bool(True)            # only delta scattering (or none) since the camera: no MIS
        self.last_p, self.last_pdf = o, Float(1.0)   # the last real scattering event and its pdf
        self.needs_hit = Bool(True)
        self.hit_t, self.hit_prim = Float(INF), UInt32(NO_PRIM)
        self.hit_b1, self.hit_b2, self.hit_p = Float(0.0), Float(0.0), Array3f(0.0)
        self.rays = UInt32(0)
        self.r = Array3f(1.0)                 # the channels' distance densities over the chosen channel's


def volpath_radiance(geo: SceneGeometry, o: Array3f, d: Array3f, t_min: Float, t_max: Float, rng: PCG32,
                     max_depth: UInt32, rr_depth: UInt32, spectral_mis: bool = False) -> tuple[Array3f, UInt32]:
    """Radiance along each camera ray (from t_min to t_max) and the rays each path traced; with spectral_mis
    volpathmis's estimator (the channels' distance sampling by the balance heuristic), else volpath's."""
    media = geo.media
    channel = dr.minimum(UInt32(rng.next_float32() * 3.0), 2)
    medium = UInt32(media.camera if media is not None else VACUUM)
    o = dr.fma(d, t_min, o)
    state = VolState(o, d, t_max - t_min, medium, channel, Bool(max_depth > 0))
    return trace_paths(geo, rng, state, _step, max_depth, rr_depth, spectral_mis)


def _step(geo: SceneGeometry, rng: PCG32, st: VolState, max_depth: UInt32, rr_depth: UInt32, mis: bool) -> None:
    """One step of each path (volpath.cpp's loop body): Russian roulette, the ray's surface hit where it has
    none yet, a collision in the lane's medium (_medium_collision), then the surface where the ray reaches it
    (_surface)."""
    media = geo.media
    active = st.active & (dr.max(st.beta) > 0)
    q = dr.minimum(dr.max(_throughput(st.beta, st.r, mis)) * st.eta * st.eta, Q_MAX)
    rr = st.depth > rr_depth
    active &= (rng.next_float32() < q) | ~rr
    st.beta = dr.select(rr, st.beta / q, st.beta)
    active &= st.depth < max_depth

    need = active & st.needs_hit
    hit = geo.closest_hit(st.o, st.d, 0.0, dr.select(need, st.t_max, 0.0), st.skip)
    st.rays += dr.select(need, 1, 0)
    st.hit_t = dr.select(need, dr.select(hit.valid, hit.t, INF), st.hit_t)
    st.hit_prim = dr.select(need, hit.prim, st.hit_prim)
    st.hit_b1, st.hit_b2 = dr.select(need, hit.b1, st.hit_b1), dr.select(need, hit.b2, st.hit_b2)
    st.hit_p = dr.select(need, hit.p, st.hit_p)
    st.needs_hit &= ~need

    on_surface = active
    moving = Bool(False)                 # lanes that collided in a medium (really or not) and go on
    if media is not None:
        on_surface, moving = _medium_collision(geo, rng, st, active, max_depth, mis)
        active &= st.depth < max_depth
    _surface(geo, rng, st, on_surface, max_depth, mis)
    st.active = active & (on_surface & (st.hit_prim != NO_PRIM) | moving)


def _throughput(beta: Array3f, r: Array3f, mis: bool) -> Array3f:
    """What a contribution is weighted by: beta (f / p_c, volpath's), or with spectral MIS f / mean_k(p_k)."""
    if not mis:
        return beta
    mean = _mean(r)
    return dr.select(mean > 0, beta / mean, 0.0)


def _medium_collision(geo, rng, st: VolState, active: Bool, max_depth: UInt32, mis: bool) -> tuple[Bool, Bool]:
    """The lane's next real collision in its medium, or its escape to the surface (volpath.cpp's medium
    branch, its null collisions tracked in one loop: _track); a real one adds next-event estimation and
    samples the phase function. Returns the lanes that go on to the surface (in no medium, or through it to
    the surface) and those that collided."""
    media = geo.media
    in_medium = active & (st.medium != VACUUM)
    escaped, real, p, weight = _track(media, rng, st, in_medium)
    st.depth = dr.select(real, st.depth + 1, st.depth)
    st.last_p = dr.select(real, p, st.last_p)
    collided = real
    real &= st.depth < max_depth
    st.beta = dr.select(real, st.beta * weight, st.beta)
    emitters = real & media.sample_emitters(st.medium)
    st.specular = (st.specular & ~real) | (real & ~emitters)
    if geo.has_lights:
        ld = light_direction(geo, p, rng.next_float32(), rng.next_float32(), rng.next_float32())
        lw, pdf_light = light_weight(geo, ld)
        phase = media.phase_eval(st.medium, st.d, ld.w)
        lit = emitters & (ld.cos_y > 0) & (ld.dist2 > 0)
        tr_light, r_light, rays = transmittance(geo, rng, p, UInt32(NO_PRIM), st.medium, ld, st.channel, lit)
        st.rays += rays
        st.L += dr.select(lit, _throughput(st.beta, st.r * r_light, mis) * phase * ld.ls.radiance * lw * tr_light
                          * power_heuristic(pdf_light, phase), Array3f(0.0))
    wo, phase_pdf = media.phase_sample(st.medium, st.d, Array2f(rng.next_float32(), rng.next_float32()))
    real &= phase_pdf > 0
    st.o, st.d = dr.select(real, p, st.o), dr.select(real, wo, st.d)
    st.skip, st.t_max = dr.select(real, NO_PRIM, st.skip), dr.select(real, INF, st.t_max)
    st.needs_hit |= real
    st.last_pdf = dr.select(real, phase_pdf, st.last_pdf)
    on_surface = (active & (st.medium == VACUUM)) | escaped
    return on_surface, collided


@dr.syntax
def _track(media, rng, st: VolState, active: Bool) -> tuple[Bool, Bool, Array3f, Array3f]:
    """Delta tracking from the ray's origin towards its surface hit: collisions sampled with the channel's
    majorant until a real one (a homogeneous medium has no null ones) or the surface. Each step weighs the
    throughput as volpath.cpp's: tr / pdf, then sigma_n / P(null) at a null collision, where the extinction
    is spectral. Returns (escaped to the surface, collided really, the collision point, the throughput
    factor of the real collision: sigma_s / mean(sigma_t / majorant), or sigma_s / sigma_t). The path's
    relative densities st.r take each step's channel densities over the chosen channel's."""
    escaped, real = Bool(False), Bool(False)
    p, weight = Array3f(st.o), Array3f(0.0)
    beta, r, o, hit_t, going = Array3f(st.beta), Array3f(st.r), Array3f(st.o), Float(st.hit_t), Bool(active)
    spectral = media.spectral(st.medium)
    while going:
        mi = media.sample_interaction(st.medium, o, st.d, st.t_max, rng.next_float32(), st.channel, going)
        mi.t = dr.select(hit_t < mi.t, INF, mi.t)
        tr, pdf = _free_flight(mi, hit_t, hit_t < mi.t)
        tr_pdf = channel_value(pdf, st.channel)
        beta = dr.select(going & spectral, beta * dr.select(tr_pdf > 0, tr / tr_pdf, 0.0), beta)
        r = dr.select(going & spectral, r * dr.select(tr_pdf > 0, pdf / tr_pdf, 0.0), r)
        escaped |= going & ~mi.valid
        collided = going & mi.valid
        null_prob = _mean(mi.sigma_n / mi.combined)
        null = collided & (rng.next_float32() < null_prob)
        beta = dr.select(null & spectral, beta * mi.sigma_n / null_prob, beta)
        o = dr.select(null, mi.p, o)
        hit_t = dr.select(null, hit_t - mi.t, hit_t)
        hit = collided & ~null
        real |= hit
        p = dr.select(hit, mi.p, p)
        weight = dr.select(hit, dr.select(spectral, mi.sigma_s / _mean(mi.sigma_t / mi.combined),
                                          mi.sigma_s / mi.sigma_t), weight)
        going = null & (dr.max(beta) > 0)
    st.beta, st.r, st.o = dr.select(active, beta, st.beta), dr.select(active, r, st.r), dr.select(active, o, st.o)
    st.hit_t = dr.select(active, hit_t, st.hit_t)
    return escaped, real, p, weight


def _free_flight(mi, hit_t: Float, reached: Bool) -> tuple[Array3f, Array3f]:
    """The transmittance over the sampled segment and the density of having sampled it (Mitsuba's
    transmittance_eval_pdf): tr where the ray reached the surface, tr * majorant at a collision."""
    t = dr.minimum(mi.t, hit_t) - mi.mint
    tr = dr.exp(-t * mi.combined)
    return tr, dr.select(reached, tr, tr * mi.combined)


def _mean(v: Array3f) -> Float:
    return (v.x + v.y + v.z) * (1.0 / 3.0)


def _surface(geo, rng, st: VolState, on_surface: Bool, max_depth: UInt32, mis: bool) -> None:
    """The surface the ray reached (volpath.cpp's surface branch): emission (MIS against the emitter's
    density from the last real scattering event), next-event estimation, BSDF sampling, medium transitions."""
    hit = Hit(st.hit_t, st.hit_prim, st.hit_b1, st.hit_b2, st.hit_p)
    surf = geo.surface(hit)
    d, wi = st.d, -st.d
    if geo.has_lights:
        le = geo.emitted(surf, wi)
        on_light = on_surface & (dr.max(le) > 0)
        count_direct = (st.depth == 0) | st.specular
        dist2 = dr.squared_norm(surf.p - st.last_p)
        cos_l = dr.abs(dr.dot(surf.ns, d))
        pdf_light = geo.light_pdf_area(surf) * dr.select(on_light, dist2, 0.0) / dr.maximum(cos_l, 1e-30)
        if geo.has_environment:
            pdf_light = dr.select(surf.valid, pdf_light, geo.environment_pdf(d))
        w = dr.select(count_direct, 1.0, power_heuristic(st.last_pdf, pdf_light))
        st.L += dr.select(on_light, _throughput(st.beta, st.r, mis) * le * w, Array3f(0.0))
    on_surface &= surf.valid
    bsdf = SurfaceBSDF(geo.materials, surf, wi, on_surface)
    if geo.has_lights:
        nee = on_surface & bsdf.smooth & (st.depth + 1 < max_depth)
        ld = light_direction(geo, surf.p, rng.next_float32(), rng.next_float32(), rng.next_float32())
        f, pdf_bsdf = bsdf.eval_pdf(ld.w, nee)
        lw, pdf_light = light_weight(geo, ld)
        lit = nee & (dr.max(f) > 0) & (ld.cos_y > 0) & (ld.dist2 > 0)
        medium = geo.media.target(surf, ld.w, st.medium) if geo.media is not None else UInt32(VACUUM)
        tr_light, r_light, rays = transmittance(geo, rng, surf.p, surf.prim, medium, ld, st.channel, lit)
        st.rays += rays
        st.L += dr.select(lit, _throughput(st.beta, st.r * r_light, mis) * f * ld.ls.radiance * lw * tr_light
                          * power_heuristic(pdf_light, pdf_bsdf), Array3f(0.0))
    u1 = rng.next_float32()
    bs, weight = bsdf.sample(u1, Array2f(rng.next_float32(), rng.next_float32()), on_surface)
    st.beta = dr.select(on_surface, st.beta * weight, st.beta)
    st.eta = dr.select(on_surface, st.eta * bs.eta, st.eta)
    st.o, st.d = dr.select(on_surface, surf.p, st.o), dr.select(on_surface, bs.wo, st.d)
    st.skip, st.t_max = dr.select(on_surface, surf.prim, st.skip), dr.select(on_surface, INF, st.t_max)
    st.needs_hit |= on_surface
    real = on_surface & ~has_flag(bs.sampled_type, NULL)
    st.depth = dr.select(real, st.depth + 1, st.depth)
    st.last_p, st.last_pdf = dr.select(real, surf.p, st.last_p), dr.select(real, bs.pdf, st.last_pdf)
    st.specular |= real & has_flag(bs.sampled_type, DELTA)
    st.specular &= ~(on_surface & has_flag(bs.sampled_type, SMOOTH))
    if geo.media is not None:
        st.medium = dr.select(on_surface, geo.media.target(surf, bs.wo, st.medium), st.medium)


def transmittance(geo, rng, p: Array3f, skip: UInt32, medium: UInt32, ld, channel: UInt32,
                  active: Bool) -> tuple[Array3f, Array3f, UInt32]:
    """The transmittance of the shadow ray from p towards the light sample `ld` (volpath.cpp's
    sample_emitter), starting in `medium`, the channels' densities of its sampled distances over the chosen
    channel's (VolState.r), and the rays it traced. Without media and surfaces with a null lobe the
    transmittance is visibility (geo.occluded)."""
    if geo.media is None and not geo.materials_pass_light:
        occluded = geo.occluded(p, ld.w, ld.dist, skip, ld.ls.prim, active)
        return (dr.select(active & ~occluded, Array3f(1.0), Array3f(0.0)), Array3f(1.0),
                dr.select(active, UInt32(1), UInt32(0)))
    batch, geo.batch = geo.batch, False          # the BVH walks inside the loop's kernel
    try:
        return _ratio_tracking(geo, rng, p, skip, medium, ld, channel, active)
    finally:
        geo.batch = batch


@dr.syntax
def _ratio_tracking(geo, rng, o: Array3f, skip: UInt32, medium: UInt32, ld, channel: UInt32,
                    active: Bool) -> tuple[Array3f, Array3f, UInt32]:
    """The shadow ray surface by surface: the transmittance of the media between (_segment), times each
    surface's null transmission (0 for an opaque one); the ray stops SHADOW_EPSILON short of the light."""
    segment = _segment if geo.media is not None else _vacuum
    d = Array3f(ld.w)
    max_dist = ld.dist * (1.0 - SHADOW_EPSILON)
    tr, r, total, rays = Array3f(1.0), Array3f(1.0), Float(0.0), UInt32(0)
    o, skip, medium, active = Array3f(o), UInt32(skip), UInt32(medium), Bool(active)
    while active:
        remaining = max_dist - total
        active &= remaining > 0
        hit = geo.closest_hit(o, d, 0.0, dr.select(active, remaining, 0.0), skip)
        rays += dr.select(active, 1, 0)
        hit_t = dr.select(hit.valid, hit.t, INF)
        tr, r, moved, passed, surface = segment(geo.media, rng, o, d, remaining, hit_t, medium, channel, active, tr, r)
        total = dr.select(passed, max_dist, dr.select(surface, total + hit_t, total + moved))
        hit = Hit(hit_t - moved, hit.prim, hit.b1, hit.b2, hit.p)
        surface &= hit.valid
        surf = geo.surface(hit)
        bsdf = SurfaceBSDF(geo.materials, surf, -d, surface)
        tr = dr.select(surface, tr * bsdf.null_transmission(surface), tr)
        o, skip = dr.select(surface, surf.p, o), dr.select(surface, surf.prim, skip)
        active &= surface & (dr.max(tr) > 0)
        medium = _crossed(geo.media, surf, d, medium, surface)
    return tr, r, rays


@dr.syntax
def _segment(media, rng, o: Array3f, d: Array3f, remaining: Float, hit_t: Float, medium: UInt32, channel: UInt32,
             active: Bool, tr: Array3f, r: Array3f) -> tuple[Array3f, Array3f, Float, Bool, Bool]:
    """Ratio tracking (Novak et al. 2014) along a shadow ray in its medium up to its surface hit at hit_t or the
    light at `remaining`, as volpath.cpp's sample_emitter steps it: collisions sampled with the channel's
    majorant, the transmittance weighted by the channels' transmittance over the sampling density and by
    sigma_n (over the majorant, where the extinction is not spectral) at each collision, all of which are null
    ones to a shadow ray (in a homogeneous medium sigma_n is 0: the ray gets through only where the sampled
    distance passes the surface or the light). Returns (tr, r times the channels' densities of the sampled
    distances over the chosen channel's, the distance moved, passed the light, reached the surface: lanes in
    no medium included)."""
    moved, passed, going = Float(0.0), Bool(False), active & (medium != VACUUM)
    spectral = media.spectral(medium)
    surface = active & ~going
    while going:
        left = remaining - moved
        mi = media.sample_interaction(medium, o, d, left, rng.next_float32(), channel, going)
        mi.t = dr.select(hit_t - moved < mi.t, INF, mi.t)
        t = dr.minimum(left, dr.minimum(mi.t, hit_t - moved)) - mi.mint
        tr_seg = dr.exp(-t * mi.combined)
        pdf = dr.select((hit_t - moved < mi.t) | (mi.t > left), tr_seg, tr_seg * mi.combined)
        tr_pdf = channel_value(pdf, channel)
        tr = dr.select(going & spectral, tr * dr.select(tr_pdf > 0, tr_seg / tr_pdf, 0.0), tr)
        r = dr.select(going & spectral, r * dr.select(tr_pdf > 0, pdf / tr_pdf, 0.0), r)
        beyond = going & (mi.t > left)
        passed |= beyond & dr.isfinite(mi.t)
        mi.t = dr.select(beyond, INF, mi.t)
        collided = going & dr.isfinite(mi.t)
        surface |= going & ~collided & ~passed
        moved = dr.select(collided, moved + mi.t, moved)
        o = dr.select(collided, mi.p, o)
        tr = dr.select(collided, dr.select(spectral, tr * mi.sigma_n, tr * mi.sigma_n / mi.combined), tr)
        going = collided & (dr.max(tr) > 0)
    return tr, r, moved, passed, surface


def _vacuum(media, rng, o, d, remaining, hit_t, medium, channel, active, tr, r):
    """_segment in a scene without media: straight to the surface."""
    return tr, r, Float(0.0), Bool(False), Bool(active)


def _crossed(media, surf, d, medium, crossing):
    """The medium after crossing surface `surf` along d, where `crossing`."""
    if media is None:
        return medium
    return dr.select(crossing, media.target(surf, d, medium), medium)
