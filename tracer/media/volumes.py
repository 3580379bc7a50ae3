"""Volumes, Mitsuba 3's spatially varying quantities of a medium: `constvolume` (one value everywhere) and
`gridvolume` (a voxel grid read from Mitsuba's binary `.vol` format, interpolated trilinearly or by
nearest voxel). Both live in the unit cube [0, 1]^3 of their local frame, placed by `to_world`; the cube is
the volume's bounding box (a heterogeneous medium's density is zero outside it).

The `.vol` format (Mitsuba's VolumeGrid): the bytes 'VOL', version 3, then little-endian int32 encoding
(1: float32, the only one Mitsuba reads), the x, y, z resolutions and the channel count, six float32 of a
bounding box, then the voxels as float32, x fastest, each voxel's channels together."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import drjit as dr
import numpy as np

from ..jit import HOST_FLOAT, Array3f, Float, TensorXf, Texture3f

PLUGINS = {"constvolume": ("value", "to_world"),
           "gridvolume": ("filename", "to_world", "filter_type", "wrap_mode", "use_grid_bbox", "raw", "accel",
                          "max_value", "grid", "data")}
FILTERS = {"trilinear": dr.FilterMode.Linear, "nearest": dr.FilterMode.Nearest}
WRAPS = {"clamp": dr.WrapMode.Clamp, "repeat": dr.WrapMode.Repeat, "mirror": dr.WrapMode.Mirror}


class VolumeFileError(ValueError):
    pass


@dataclass(frozen=True, eq=False)
class ConstVolume:
    value: tuple[float, float, float]
    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))

    @property
    def max(self) -> float:
        return max(self.value)


@dataclass(frozen=True, eq=False)
class GridVolume:
    data: np.ndarray                      # (z, y, x, channels) float32, channels 1 or 3
    to_world: np.ndarray
    filter: str = "trilinear"
    wrap: str = "clamp"

    @property
    def max(self) -> float:
        return float(self.data.max())


def read_vol(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The voxels (z, y, x, channels) and the bounding box (2, 3) of a `.vol` file."""
    raw = path.read_bytes()
    if len(raw) < 48 or raw[:3] != b"VOL":
        raise VolumeFileError(f"{path.name}: not a Mitsuba .vol file (it must start with 'VOL')")
    if raw[3] != 3:
        raise VolumeFileError(f"{path.name}: .vol version {raw[3]}; supported: 3 (as Mitsuba)")
    encoding, nx, ny, nz, channels = np.frombuffer(raw, "<i4", 5, 4)
    if encoding != 1:
        raise VolumeFileError(f"{path.name}: .vol encoding {encoding}; supported: 1 (float32, as Mitsuba)")
    if min(nx, ny, nz) < 1 or channels not in (1, 3):
        raise VolumeFileError(f"{path.name}: a {nx} x {ny} x {nz} grid of {channels} channels; supported: "
                              "positive sizes, 1 or 3 channels")
    count = int(nx) * int(ny) * int(nz) * int(channels)
    if len(raw) != 48 + 4 * count:
        raise VolumeFileError(f"{path.name}: {len(raw)} bytes; a {nx} x {ny} x {nz} grid of {channels} channels "
                              f"takes {48 + 4 * count}")
    bbox = np.frombuffer(raw, "<f4", 6, 24).reshape(2, 3).astype(float)
    data = np.frombuffer(raw, "<f4", count, 48).reshape(nz, ny, nx, channels)
    if not np.all(np.isfinite(data)):
        raise VolumeFileError(f"{path.name}: the grid holds values that are not finite")
    return data.copy(), bbox


def grid_bbox_transform(bbox: np.ndarray) -> np.ndarray:
    """The transform from the unit cube to the grid's own bounding box (`use_grid_bbox`)."""
    m = np.eye(4)
    m[:3, :3] = np.diag(bbox[1] - bbox[0])
    m[:3, 3] = bbox[0]
    return m


class VolumeKernel:
    """A volume as kernel code: eval(p) at world points, and its bounding box's ray interval."""

    def __init__(self, volume: ConstVolume | GridVolume):
        self.volume = volume
        to_local = np.linalg.inv(volume.to_world)
        self.to_local = [[float(x) for x in row] for row in to_local[:3]]
        self.texture = None
        if isinstance(volume, GridVolume):
            self.texture = Texture3f(TensorXf(volume.data.astype(HOST_FLOAT)),
                                     use_accel=False, filter_mode=FILTERS[volume.filter],
                                     wrap_mode=WRAPS[volume.wrap])

    def local(self, p: Array3f) -> Array3f:
        m = self.to_local
        return Array3f(*(m[i][0] * p.x + m[i][1] * p.y + m[i][2] * p.z + m[i][3] for i in range(3)))

    def eval(self, p: Array3f, active=True) -> Array3f:
        if self.texture is None:
            return Array3f(*(float(v) for v in self.volume.value))
        value = self.texture.eval(self.local(p), active)
        return Array3f(value[0]) if len(value) == 1 else Array3f(value[0], value[1], value[2])

    def interval(self, o: Array3f, d: Array3f) -> tuple:
        """(hit, t0, t1): where the ray o + t d runs inside the unit cube of the local frame (slab method)."""
        lo, ld = self.local(o), self.local_vector(d)
        t0, t1 = Float(-np.inf), Float(np.inf)
        for k in range(3):
            inv = dr.rcp(ld[k])
            a, b = -lo[k] * inv, (1.0 - lo[k]) * inv
            parallel = ld[k] == 0
            inside = (lo[k] >= 0) & (lo[k] <= 1)
            t0 = dr.select(parallel, dr.select(inside, t0, np.inf), dr.maximum(t0, dr.minimum(a, b)))
            t1 = dr.select(parallel, dr.select(inside, t1, -np.inf), dr.minimum(t1, dr.maximum(a, b)))
        return t0 <= t1, t0, t1

    def local_vector(self, v: Array3f) -> Array3f:
        m = self.to_local
        return Array3f(*(m[i][0] * v.x + m[i][1] * v.y + m[i][2] * v.z for i in range(3)))

