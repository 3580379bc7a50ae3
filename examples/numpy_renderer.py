"""A renderer written against `{scene_json}` alone (no Mitsuba, nothing of the project): a small NumPy path
tracer of Mitsuba's `path` integral, to show the contract is enough to take a renderer through validate check.

    R="python examples/numpy_renderer.py {scene_json} --spp {spp} --seeds {seeds} --outputs {outputs}"
    validate check mitsuba_scenes/cornell_box.xml --renderer "$R" --jobs 2

It renders untextured diffuse (one- or two-sided) surfaces, smooth conductors (the Fresnel reflectance of
eta + i k, times specular_reflectance) and smooth dielectrics (Fresnel-weighted choice of reflection or
refraction), area emitters on triangle meshes and spheres (front side only), point, spot and directional lights
and a constant environment, through triangle meshes (brute force within each shape's bounding box: a few
thousand triangles at most) and spheres (their analytic description), with the box pixel filter and a pinhole
perspective camera. Anything else exits with status 77 and the reason on stderr, which the check reports as
"skipped: unsupported". The estimator: next-event estimation at diffuse vertices (one area-light point chosen by
area, and every delta light), emission found by the path counted only after the camera or a specular bounce (so
nothing is counted twice), Russian roulette from the scene's rr_depth; a path of d vertices is counted only
where d <= max_depth (Mitsuba's depth). `--scale` multiplies the image: a deliberate mistake, to see the check
catch it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import OpenEXR
from plyfile import PlyData

UNSUPPORTED = 77
EPS = 1e-4
MAX_TRIANGLES = 4096


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", type=Path)
    ap.add_argument("--spp", type=int, required=True)
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--outputs", required=True)
    ap.add_argument("--scale", type=float, default=1.0, help="multiply the image (a deliberate mistake)")
    args = ap.parse_args()
    scene = Scene(json.loads(args.scene.read_text()), args.scene.parent)
    for seed, output in zip(args.seeds.split(","), args.outputs.split(",")):
        image = args.scale * scene.render(args.spp, np.random.default_rng(int(seed)))
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": image.astype(np.float32)}) as f:
            f.write(output)


def unsupported(why: str):
    print(f"numpy_renderer: {why}", file=sys.stderr)
    sys.exit(UNSUPPORTED)


class Scene:
    def __init__(self, data: dict, folder: Path):
        if data["camera"]["type"] != "perspective" or data["camera"]["aperture_radius"] > 0:
            unsupported(f"the {data['camera']['type']} camera, aperture {data['camera']['aperture_radius']} "
                        "(a pinhole perspective camera only)")
        if data["integrator"]["type"] != "path":
            unsupported(f"the {data['integrator']['type']} integrator (path only)")
        self.width, self.height = data["film"]["width"], data["film"]["height"]
        if data["film"]["filter"]["type"] != "box":
            unsupported(f"the {data['film']['filter']['type']} pixel filter (box only)")
        self.depth, self.rr_depth = data["integrator"]["max_depth"], data["integrator"]["rr_depth"]
        self.camera = np.array(data["camera"]["to_world"])
        self.tan = data["camera"]["tan_half_fov"]
        self.env = np.zeros(3)
        self.points, self.directionals = [], []       # delta lights: (position, intensity, spot cone or None)
        for e in data["emitters"]:
            if e["type"] == "constant":
                self.env = np.array(e["radiance"])
            elif e["type"] in ("point", "spot"):
                cone = None if e["type"] == "point" else (np.array(e["direction"]), np.radians(e["cutoff_angle"]),
                                                          np.radians(e["beam_width"]))
                self.points.append((np.array(e["position"]), np.array(e["intensity"]), cone))
            elif e["type"] == "directional":
                self.directionals.append((np.array(e["direction"]), np.array(e["irradiance"])))
            else:
                unsupported(f"the '{e['type']}' emitter (constant, point, spot, directional and area lights only)")
        self._materials([self._material(m) for m in data["materials"]])
        tris, tri_mat, tri_emit, spheres = [], [], [], []
        for s in data["shapes"]:
            emit = np.zeros(3) if s["emitter"] is None else np.array(s["emitter"]["radiance"])
            if s["type"] == "sphere":
                spheres.append((np.array(s["analytic"]["center"]), s["analytic"]["radius"], s["material"], emit))
                continue
            ply = PlyData.read(str(folder / s["mesh"]))
            v = np.stack([ply["vertex"][c] for c in "xyz"], 1).astype(np.float64)
            f = np.stack(ply["face"]["vertex_indices"]).astype(np.int64)
            tris.append(v[f])
            tri_mat += [s["material"]] * len(f)
            tri_emit += [emit] * len(f)
        self.tris = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
        ends = np.cumsum([len(t) for t in tris]).tolist()
        self.groups = [(a, b, self.tris[a:b].min((0, 1)) - EPS, self.tris[a:b].max((0, 1)) + EPS)
                       for a, b in zip([0] + ends[:-1], ends)]      # each shape's triangles and bounding box
        if len(self.tris) > MAX_TRIANGLES:
            unsupported(f"{len(self.tris)} triangles (brute force: {MAX_TRIANGLES} at most)")
        self.tri_mat, self.tri_emit = np.array(tri_mat, int), np.array(tri_emit).reshape(-1, 3)
        self.spheres = spheres
        e1, e2 = self.tris[:, 1] - self.tris[:, 0], self.tris[:, 2] - self.tris[:, 0]
        cross = np.cross(e1, e2)
        self.area = 0.5 * np.linalg.norm(cross, axis=1)
        self.normal = cross / np.maximum(2 * self.area, 1e-30)[:, None]
        # area lights, chosen by area: the emitting triangles, then the emitting spheres (index -1 - sphere)
        lit = np.nonzero(np.any(self.tri_emit > 0, axis=1))[0]
        lit_spheres = [i for i, s in enumerate(spheres) if np.any(s[3] > 0)]
        self.lights = np.concatenate([lit, -1 - np.array(lit_spheres, int)])
        areas = np.concatenate([self.area[lit], [4 * np.pi * spheres[i][1] ** 2 for i in lit_spheres]])
        self.light_area = areas.sum()
        self.light_cdf = np.cumsum(areas) / self.light_area if len(areas) else None

    @staticmethod
    def _material(m: dict) -> dict:
        why = (m["type"] not in ("diffuse", "conductor", "dielectric") and "diffuse, smooth conductors and smooth "
               "dielectrics only" or m["texture"] is not None and "a texture" or m["normalmap"] is not None and
               "a normal map" or m["opacity"] != 1 and "an opacity mask" or m["blend"] is not None and "a blend" or
               m["twosided"] and m["back"] is not None and "a different back side" or
               m["type"] == "dielectric" and m["specular_transmittance"] != [1.0, 1.0, 1.0] and
               "a specular_transmittance other than 1")
        if why:
            unsupported(f"the material '{m['type']}': {why}")
        return m

    def _materials(self, materials: list[dict]) -> None:
        """Per-material arrays, indexed by a hit's material: kind (0 diffuse, 1 conductor, 2 dielectric) and
        parameters."""
        kinds = {"diffuse": 0, "conductor": 1, "dielectric": 2}
        self.kind = np.array([kinds[m["type"]] for m in materials], int)
        self.twosided = np.array([m["twosided"] or m["type"] == "dielectric" for m in materials], bool)
        self.albedo = np.array([m["reflectance"] if m["type"] == "diffuse" else [0.0] * 3 for m in materials])
        self.eta = np.array([m["eta"] for m in materials], float)
        self.k = np.array([m["k"] for m in materials], float)
        self.tint = np.array([m["specular_reflectance"] for m in materials], float)
        self.ior = np.array([m["int_ior"] / m["ext_ior"] for m in materials])

    # ---- rays --------------------------------------------------------------------------------------------
    def intersect(self, o: np.ndarray, d: np.ndarray, t_max: np.ndarray | None = None):
        """Nearest hit: (t, triangle index or -1 - sphere index, hit found)."""
        n = len(o)
        best = np.full(n, np.inf) if t_max is None else t_max.copy()
        which = np.full(n, -(10 ** 9), int)
        inv_d = 1.0 / np.where(d == 0, 1e-30, d)
        for first, last, lo, hi in self.groups:                # rays that enter a shape's box meet its triangles
            t0, t1 = (lo - o) * inv_d, (hi - o) * inv_d
            near, far = np.minimum(t0, t1).max(1), np.maximum(t0, t1).min(1)
            rays = np.nonzero((near <= far) & (far > EPS) & (near < best))[0]
            for chunk in range(first, last, 256):
                if len(rays):
                    self._triangles(o[rays], d[rays], chunk, min(chunk + 256, last), rays, best, which)
        for i, (c, r, _, _) in enumerate(self.spheres):
            oc = o - c
            b = np.einsum("rk,rk->r", oc, d)
            disc = b * b - (np.einsum("rk,rk->r", oc, oc) - r * r)
            root = np.sqrt(np.maximum(disc, 0))
            t = np.where(-b - root > EPS, -b - root, -b + root)
            t = np.where((disc > 0) & (t > EPS), t, np.inf)
            closer = t < best
            best[closer], which[closer] = t[closer], -1 - i
        return best, which, which > -(10 ** 9)

    def _triangles(self, o, d, first: int, last: int, rays, best, which) -> None:
        """Moeller-Trumbore, vectorised over rays x triangles first..last; nearer hits update best and which."""
        tri = self.tris[first:last]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        p = np.cross(d[:, None], e2[None])
        det = np.einsum("rtk,tk->rt", p, e1)
        inv = 1.0 / np.where(np.abs(det) < 1e-12, np.inf, det)
        s = o[:, None] - tri[None, :, 0]
        u = np.einsum("rtk,rtk->rt", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("rk,rtk->rt", d, q) * inv
        t = np.einsum("tk,rtk->rt", e2, q) * inv
        ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > EPS) & (np.abs(det) >= 1e-12)
        t = np.where(ok, t, np.inf)
        j = np.argmin(t, axis=1)
        tj = t[np.arange(len(rays)), j]
        closer = tj < best[rays]
        best[rays[closer]], which[rays[closer]] = tj[closer], first + j[closer]

    def occluded(self, p: np.ndarray, n: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Whether anything lies between p, offset along n, and the points `target`. The segment starts at the
        offset point: a ray from there parallel to target - p would meet the target's plane EPS / cos sooner,
        and at grazing angles take the emitter itself for a blocker."""
        o = p + EPS * n
        to = target - o
        dist = np.linalg.norm(to, axis=1)
        t, _, _ = self.intersect(o, to / dist[:, None], dist - EPS)
        return t < dist - EPS

    def occluded_towards(self, p: np.ndarray, n: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Whether anything lies along wi from p (offset along n): a light at infinity's shadow ray."""
        return self.intersect(p + EPS * n, wi)[2]

    def surface(self, p: np.ndarray, which: np.ndarray):
        """(geometric normal, material index, emitted radiance) at hits."""
        n = np.zeros_like(p)
        mat = np.zeros(len(p), int)
        emit = np.zeros_like(p)
        tri = which >= 0
        n[tri], mat[tri], emit[tri] = self.normal[which[tri]], self.tri_mat[which[tri]], self.tri_emit[which[tri]]
        for i, (c, r, m, e) in enumerate(self.spheres):
            s = which == -1 - i
            n[s], mat[s], emit[s] = (p[s] - c) / r, m, e
        return n, mat, emit

    # ---- the estimator ---------------------------------------------------------------------------------
    def render(self, spp: int, rng: np.random.Generator) -> np.ndarray:
        h, w = self.height, self.width
        py, px = np.divmod(np.repeat(np.arange(h * w), spp), w)
        x = (px + rng.random(len(px))) / w
        y = (py + rng.random(len(py))) / h
        local = np.stack([(1 - 2 * x) * self.tan[0], (1 - 2 * y) * self.tan[1], np.ones_like(x)], 1)   # x left
        d = local @ self.camera[:3, :3].T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.broadcast_to(self.camera[:3, 3], d.shape).copy()
        radiance = self.trace(o, d, rng)
        image = np.zeros((h * w, 3))
        np.add.at(image, py * w + px, radiance)
        return (image / spp).reshape(h, w, 3)

    def trace(self, o, d, rng) -> np.ndarray:
        n_rays = len(o)
        out = np.zeros((n_rays, 3))
        beta = np.ones((n_rays, 3))
        alive = np.arange(n_rays)
        count_emission = np.ones(n_rays, bool)    # after the camera or a specular (delta) bounce
        depth = 1
        while len(alive) and (self.depth < 0 or depth <= self.depth):
            t, which, hit = self.intersect(o, d)
            if not hit.all():
                miss = ~hit
                out[alive[miss]] += beta[miss] * self.env          # next-event estimation leaves the sky out
                keep = hit
                alive, o, d, beta, t, which, count_emission = (a[keep] for a in (alive, o, d, beta, t, which,
                                                                               count_emission))
            p = o + t[:, None] * d
            ng, mat, emit = self.surface(p, which)
            cos_i = -np.einsum("rk,rk->r", ng, d)
            front = cos_i > 0
            counted = count_emission & front
            out[alive[counted]] += beta[counted] * emit[counted]
            if self.depth >= 0 and depth == self.depth:
                break
            kind, lit = self.kind[mat], front | self.twosided[mat]
            n = np.where(front[:, None], ng, -ng)                  # the normal on the incoming side
            cos_i = np.abs(cos_i)
            new_d, weight = np.zeros_like(d), np.zeros_like(beta)
            diffuse = lit & (kind == 0)
            if diffuse.any():
                albedo = self.albedo[mat[diffuse]]
                out[alive[diffuse]] += beta[diffuse] * albedo * self.next_event(p[diffuse], n[diffuse], rng)
                new_d[diffuse] = cosine_direction(n[diffuse], rng)
                weight[diffuse] = albedo
            mirror = lit & (kind == 1)
            if mirror.any():
                c, m = cos_i[mirror], mat[mirror]
                new_d[mirror] = d[mirror] + 2 * c[:, None] * n[mirror]
                weight[mirror] = self.tint[m] * fresnel_conductor(c, self.eta[m], self.k[m])
            glass = kind == 2
            if glass.any():
                new_d[glass], weight[glass] = self.dielectric(d[glass], n[glass], cos_i[glass], front[glass],
                                                              mat[glass], rng)
            beta = beta * weight
            count_emission = mirror | glass
            depth += 1
            if depth > self.rr_depth:                  # Russian roulette, as Mitsuba's from rr_depth
                q = np.minimum(beta.max(1), 0.95)
                survive = rng.random(len(q)) < q
                beta = beta / np.maximum(q, 1e-30)[:, None]
                keep = survive & (weight.max(1) > 0)
            else:
                keep = weight.max(1) > 0
            alive, beta, count_emission = alive[keep], beta[keep], count_emission[keep]
            side = np.where(np.einsum("rk,rk->r", new_d[keep], n[keep]) > 0, 1.0, -1.0)    # reflected or refracted
            o, d = p[keep] + EPS * side[:, None] * n[keep], new_d[keep]
        return out

    def dielectric(self, d, n, cos_i, front, mat, rng):
        """A smooth dielectric: reflect with the Fresnel probability, else refract (Snell); the refracted
        radiance scaled by 1 / eta^2 (the solid angle's compression; Veach 1997, 5.2), the weights then
        specular_reflectance and 1 / eta^2."""
        eta = np.where(front, self.ior[mat], 1 / self.ior[mat])       # eta_t / eta_i
        sin2_t = (1 - cos_i * cos_i) / (eta * eta)
        cos_t = np.sqrt(np.maximum(0, 1 - sin2_t))
        rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
        rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
        f = np.where(sin2_t >= 1, 1.0, 0.5 * (rs * rs + rp * rp))
        reflect = rng.random(len(d)) < f
        reflected = d + 2 * cos_i[:, None] * n
        refracted = d / eta[:, None] + (cos_i / eta - cos_t)[:, None] * n
        new_d = np.where(reflect[:, None], reflected, refracted)
        weight = np.where(reflect[:, None], self.tint[mat], (1 / (eta * eta))[:, None] * np.ones((1, 3)))
        return new_d, weight

    def next_event(self, p, n, rng) -> np.ndarray:
        """Direct light at diffuse points divided by their albedo: one point on the area lights (chosen by
        area), times cos / (pi pdf), plus every delta light, each unoccluded."""
        out = np.zeros_like(p)
        for position, intensity, cone in self.points:
            to = position - p
            dist = np.linalg.norm(to, axis=1)
            wi = to / dist[:, None]
            cos_x = np.einsum("rk,rk->r", wi, n)
            falloff = np.ones(len(p)) if cone is None else spot_falloff(-wi, *cone)
            ok = (cos_x > 0) & (falloff > 0) & ~self.occluded(p, n, np.broadcast_to(position, p.shape))
            out += intensity * np.where(ok, falloff * cos_x / (np.pi * dist * dist), 0)[:, None]
        for direction, irradiance in self.directionals:
            wi = np.broadcast_to(-direction, p.shape)
            cos_x = np.einsum("rk,rk->r", wi, n)
            ok = (cos_x > 0) & ~self.occluded_towards(p, n, wi)
            out += irradiance * np.where(ok, cos_x / np.pi, 0)[:, None]
        if self.light_cdf is not None:
            out += self.area_light(p, n, rng)
        return out

    def area_light(self, p, n, rng) -> np.ndarray:
        light = self.lights[np.searchsorted(self.light_cdf, rng.random(len(p)), side="right")
                            .clip(0, len(self.lights) - 1)]
        u1, u2 = rng.random(len(p)), rng.random(len(p))
        y, ny, radiance = np.zeros_like(p), np.zeros_like(p), np.zeros_like(p)
        tri = light >= 0
        su = np.sqrt(u1[tri])
        a, b, c = (self.tris[light[tri], i] for i in range(3))
        y[tri] = (1 - su)[:, None] * a + (su * (1 - u2[tri]))[:, None] * b + (su * u2[tri])[:, None] * c
        ny[tri], radiance[tri] = self.normal[light[tri]], self.tri_emit[light[tri]]
        for i, (centre, r, _, e) in enumerate(self.spheres):
            s = light == -1 - i
            z = 1 - 2 * u1[s]                                   # uniform on the sphere
            phi, rho = 2 * np.pi * u2[s], np.sqrt(np.maximum(0, 1 - z * z))
            ny[s] = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], 1)
            y[s], radiance[s] = centre + r * ny[s], e
        to = y - p
        dist = np.linalg.norm(to, axis=1)
        wi = to / dist[:, None]
        cos_x = np.einsum("rk,rk->r", wi, n)
        cos_y = -np.einsum("rk,rk->r", wi, ny)                # the emitter's front faces the point
        ok = (cos_x > 0) & (cos_y > 0)
        ok[ok] &= ~self.occluded(p[ok], n[ok], y[ok])
        g = np.where(ok, cos_x * cos_y / np.maximum(dist * dist, 1e-30), 0)
        return radiance * (g * self.light_area / np.pi)[:, None]


def spot_falloff(w: np.ndarray, axis: np.ndarray, cutoff: float, beam: float) -> np.ndarray:
    """Mitsuba's spot: 1 within beam_width of the axis, falling linearly in angle to 0 at cutoff_angle."""
    angle = np.arccos(np.clip(w @ axis, -1, 1))
    return np.where(angle <= beam, 1.0, np.clip((cutoff - angle) / max(cutoff - beam, 1e-12), 0, 1))


def cosine_direction(n: np.ndarray, rng) -> np.ndarray:
    """Cosine-weighted directions about n (Malley's method)."""
    r, phi = np.sqrt(rng.random(len(n))), 2 * np.pi * rng.random(len(n))
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0, 1 - r * r))], 1)
    t = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    s = np.cross(n, t)
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    t = np.cross(n, s)
    return local[:, :1] * s + local[:, 1:2] * t + local[:, 2:] * n


def fresnel_conductor(cos: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The unpolarised Fresnel reflectance of a conductor of complex index eta + i k (per channel)."""
    c = cos[:, None]
    n = eta + 1j * k
    sin2 = 1 - c * c
    cos_t = np.sqrt(1 - sin2 / (n * n))
    rs = (c - n * cos_t) / (c + n * cos_t)
    rp = (n * c - cos_t) / (n * c + cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


if __name__ == "__main__":
    main()
