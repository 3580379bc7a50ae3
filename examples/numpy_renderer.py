"""A renderer written against `{scene_json}` alone (no Mitsuba, nothing of the project): a small NumPy path
tracer of Mitsuba's `path` integral, to show the contract is enough to take a renderer through validate check.

    R="python examples/numpy_renderer.py {scene_json} --spp {spp} --seeds {seeds} --outputs {outputs}"
    validate check mitsuba_scenes/cornell_box.xml --renderer "$R" --jobs 2

It renders diffuse (one- or two-sided) surfaces, smooth conductors (the Fresnel reflectance of eta + i k,
times specular_reflectance), area emitters (front side only) and a constant environment, through triangle
meshes (brute force: a few thousand triangles at most) and spheres (their analytic description), with the box
pixel filter; anything else exits with status 77, which the check reports as "skipped: unsupported". The
estimator: next-event estimation at diffuse vertices (one emitter triangle chosen by area), emission found by
the path counted only after the camera or a mirror (so nothing is counted twice), Russian roulette from depth
5; a path of d vertices is counted only where d <= max_depth (Mitsuba's depth).
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
    args = ap.parse_args()
    scene = Scene(json.loads(args.scene.read_text()), args.scene.parent)
    for seed, output in zip(args.seeds.split(","), args.outputs.split(",")):
        image = scene.render(args.spp, np.random.default_rng(int(seed)))
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": image.astype(np.float32)}) as f:
            f.write(output)


def unsupported(why: str):
    print(f"numpy_renderer: {why}", file=sys.stderr)
    sys.exit(UNSUPPORTED)


class Scene:
    def __init__(self, data: dict, folder: Path):
        if data["camera"]["type"] != "perspective" or data["camera"]["aperture_radius"] > 0 \
                or data["integrator"]["type"] != "path":
            unsupported(f"the {data['camera']['type']} camera or the {data['integrator']['type']} integrator")
        self.width, self.height = data["film"]["width"], data["film"]["height"]
        if data["film"]["filter"]["type"] != "box":
            unsupported(f"the {data['film']['filter']['type']} pixel filter (box only)")
        self.depth = data["integrator"]["max_depth"]
        self.camera = np.array(data["camera"]["to_world"])
        self.tan = data["camera"]["tan_half_fov"]
        self.env = np.zeros(3)
        for e in data["emitters"]:
            if e["type"] != "constant":
                unsupported(f"the '{e['type']}' emitter")
            self.env = np.array(e["radiance"])
        self.materials = [self._material(m) for m in data["materials"]]
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
        if len(self.tris) > MAX_TRIANGLES:
            unsupported(f"{len(self.tris)} triangles (brute force: {MAX_TRIANGLES} at most)")
        self.tri_mat, self.tri_emit = np.array(tri_mat, int), np.array(tri_emit).reshape(-1, 3)
        self.spheres = spheres
        e1, e2 = self.tris[:, 1] - self.tris[:, 0], self.tris[:, 2] - self.tris[:, 0]
        cross = np.cross(e1, e2)
        self.area = 0.5 * np.linalg.norm(cross, axis=1)
        self.normal = cross / np.maximum(2 * self.area, 1e-30)[:, None]
        if any(np.any(s[3] > 0) for s in spheres):
            unsupported("an area emitter on a sphere (lights are sampled on triangles)")
        lit = np.nonzero(np.any(self.tri_emit > 0, axis=1))[0]
        self.lights = lit
        self.light_cdf = np.cumsum(self.area[lit]) / self.area[lit].sum() if len(lit) else None

    @staticmethod
    def _material(m: dict) -> dict:
        if m["type"] not in ("diffuse", "conductor") or m["texture"] is not None or m["normalmap"] is not None \
                or m["opacity"] != 1 or m["blend"] is not None or (m["twosided"] and m["back"] is not None):
            unsupported(f"the material '{m['type']}' with these parameters (diffuse and smooth conductors only)")
        if m["type"] == "diffuse":
            return {"kind": 0, "albedo": np.array(m["reflectance"]), "twosided": m["twosided"]}
        return {"kind": 1, "eta": np.array(m["eta"]), "k": np.array(m["k"]),
                "tint": np.array(m["specular_reflectance"]), "twosided": m["twosided"]}

    # ---- rays --------------------------------------------------------------------------------------------
    def intersect(self, o: np.ndarray, d: np.ndarray, t_max: np.ndarray | None = None):
        """Nearest hit: (t, triangle index or -1 - sphere index, hit found)."""
        n = len(o)
        best = np.full(n, np.inf) if t_max is None else t_max.copy()
        which = np.full(n, -(10 ** 9), int)
        for chunk in range(0, len(self.tris), 256):          # Moeller-Trumbore, vectorised over rays x triangles
            tri = self.tris[chunk:chunk + 256]
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
            tj = t[np.arange(n), j]
            closer = tj < best
            best[closer], which[closer] = tj[closer], chunk + j[closer]
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
        count_emission = np.ones(n_rays, bool)    # after the camera or a mirror
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
            front = np.einsum("rk,rk->r", ng, d) < 0
            counted = count_emission & front
            out[alive[counted]] += beta[counted] * emit[counted]
            kind = np.array([self.materials[m]["kind"] for m in range(len(self.materials))])[mat]
            twosided = np.array([self.materials[m]["twosided"] for m in range(len(self.materials))])[mat]
            lit = front | twosided
            n = np.where(front[:, None], ng, -ng)
            if self.depth >= 0 and depth == self.depth:
                break
            diffuse = lit & (kind == 0)
            albedo = np.array([self.materials[m].get("albedo", np.zeros(3)) for m in range(len(self.materials))])[mat]
            if diffuse.any():
                out[alive[diffuse]] += beta[diffuse] * albedo[diffuse] * self.next_event(p[diffuse], n[diffuse], rng)
            new_d = np.zeros_like(d)
            weight = np.zeros_like(beta)
            if diffuse.any():
                new_d[diffuse] = cosine_direction(n[diffuse], rng)
                weight[diffuse] = albedo[diffuse]
            mirror = lit & (kind == 1)
            if mirror.any():
                cos = -np.einsum("rk,rk->r", d[mirror], n[mirror])
                new_d[mirror] = d[mirror] + 2 * cos[:, None] * n[mirror]
                eta = np.array([self.materials[m].get("eta", np.zeros(3)) for m in range(len(self.materials))])[mat]
                k = np.array([self.materials[m].get("k", np.zeros(3)) for m in range(len(self.materials))])[mat]
                tint = np.array([self.materials[m].get("tint", np.zeros(3)) for m in range(len(self.materials))])[mat]
                weight[mirror] = tint[mirror] * fresnel_conductor(cos, eta[mirror], k[mirror])
            beta = beta * weight
            count_emission = mirror
            depth += 1
            if depth > 5:                              # Russian roulette, as Mitsuba's from rr_depth 5
                q = np.minimum(beta.max(1), 0.95)
                survive = rng.random(len(q)) < q
                beta = beta / np.maximum(q, 1e-30)[:, None]
                keep = survive & (weight.max(1) > 0)
            else:
                keep = weight.max(1) > 0
            alive, beta, count_emission = alive[keep], beta[keep], count_emission[keep]
            o, d = p[keep] + EPS * n[keep] * np.where(np.einsum("rk,rk->r", new_d[keep], n[keep]) > 0, 1, -1)[:, None], \
                new_d[keep]
        return out

    def next_event(self, p, n, rng) -> np.ndarray:
        """Radiance from one point on the emitters (chosen by area) times cos / (pi pdf), unoccluded: the
        diffuse vertex's direct light divided by its albedo."""
        if self.light_cdf is None:
            return np.zeros_like(p)
        tri = self.lights[np.searchsorted(self.light_cdf, rng.random(len(p)) * self.light_cdf[-1], side="right")
                          .clip(0, len(self.lights) - 1)]
        u1, u2 = rng.random(len(p)), rng.random(len(p))
        su = np.sqrt(u1)
        a, b, c = (self.tris[tri, i] for i in range(3))
        y = (1 - su)[:, None] * a + (su * (1 - u2))[:, None] * b + (su * u2)[:, None] * c
        to = y - p
        dist = np.linalg.norm(to, axis=1)
        wi = to / dist[:, None]
        cos_x = np.einsum("rk,rk->r", wi, n)
        cos_y = -np.einsum("rk,rk->r", wi, self.normal[tri])          # the emitter's front faces the point
        ok = (cos_x > 0) & (cos_y > 0)
        t, _, _ = self.intersect(p + EPS * n, wi, dist - 2 * EPS)
        ok &= ~(t < dist - 2 * EPS)
        pdf = 1.0 / self.area[self.lights].sum()
        g = np.where(ok, cos_x * cos_y / np.maximum(dist * dist, 1e-30), 0)
        return self.tri_emit[tri] * (g / (np.pi * pdf))[:, None]


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
