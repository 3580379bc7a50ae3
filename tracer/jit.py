"""The Dr.Jit backend: CUDA where a GPU is present, LLVM on the CPU otherwise.

`TRACER_BACKEND=llvm` or `=cuda` forces one; `TRACER_PRECISION=double` makes every kernel compute in
float64. Every kernel module takes its array types from here.
"""
import math
import os

import drjit as dr
import numpy as np

from .errors import BackendError


def cpu_quota() -> float | None:
    """The CPUs' worth of time this process's container may use (cgroup v2's cpu.max, else v1's
    cpu.cfs_quota_us over cpu.cfs_period_us); None where no quota is set."""
    try:
        quota, period = _read("/sys/fs/cgroup/cpu.max").split()[:2]
    except OSError:
        try:
            quota, period = _read("/sys/fs/cgroup/cpu/cpu.cfs_quota_us"), _read("/sys/fs/cgroup/cpu/cpu.cfs_period_us")
        except OSError:
            return None
    try:
        return int(quota) / int(period) if quota not in ("max", "-1") and int(period) > 0 else None
    except ValueError:
        return None


def _read(path: str) -> str:
    with open(path) as f:
        return f.read().strip()


def usable_cores() -> int:
    """The cores this process may use: those it may run on, no more than its container's quota (rounded up)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    quota = cpu_quota()
    return cores if quota is None else max(1, min(cores, math.ceil(quota)))


CORES = usable_cores()   # threads for host work that leaves the interpreter lock

LLVM_FIX = ("install an LLVM runtime >= 16 (Debian/Ubuntu: apt-get install libllvm19) or point "
            "DRJIT_LIBLLVM_PATH at its libLLVM.so")


def _pick_backend():
    wanted = os.environ.get("TRACER_BACKEND", "").lower()
    if wanted not in ("", "llvm", "cuda"):
        raise BackendError(f"TRACER_BACKEND must be 'llvm' or 'cuda', got '{wanted}'")
    if wanted == "cuda" and not dr.has_backend(dr.JitBackend.CUDA):
        raise BackendError("TRACER_BACKEND=cuda (--backend cuda): Dr.Jit finds no CUDA GPU or driver on this "
                           "machine; use the llvm backend")
    if wanted == "cuda" or (not wanted and dr.has_backend(dr.JitBackend.CUDA)):
        import drjit.cuda as backend
        return backend, "cuda"
    if not dr.has_backend(dr.JitBackend.LLVM):
        raise BackendError(f"Dr.Jit's LLVM backend is unavailable (no LLVM, or one older than 15): {LLVM_FIX}")
    if dr.detail.llvm_version()[0] < 16:  # LLVM 15 loads, then fails compiling the first kernel
        raise BackendError(f"Dr.Jit found LLVM {'.'.join(map(str, dr.detail.llvm_version()))}, which cannot "
                           f"compile the tracer's kernels: {LLVM_FIX}")
    import drjit.llvm as backend
    return backend, "llvm"


_backend, BACKEND = _pick_backend()
UInt32, UInt64, Int32, Bool, PCG32 = _backend.UInt32, _backend.UInt64, _backend.Int32, _backend.Bool, _backend.PCG32
ArrayXu = _backend.ArrayXu
PRECISION = os.environ.get("TRACER_PRECISION", "single").lower()
if PRECISION not in ("single", "double"):
    raise BackendError(f"TRACER_PRECISION must be 'single' or 'double', got '{PRECISION}'")
# double: every kernel computes in float64 (random numbers stay float32, promoted), to tell rounding from bias
Float, Array2f, Array3f, ArrayXf = (
    (_backend.Float64, _backend.Array2f64, _backend.Array3f64, _backend.ArrayXf64) if PRECISION == "double"
    else (_backend.Float, _backend.Array2f, _backend.Array3f, _backend.ArrayXf))
Texture3f, TensorXf = ((_backend.Texture3f64, _backend.TensorXf64) if PRECISION == "double"
                      else (_backend.Texture3f, _backend.TensorXf))
HOST_FLOAT = np.float64 if PRECISION == "double" else np.float32   # Float's NumPy type (tables built in it)

INF = float("inf")
NO_PRIM = 0xFFFFFFFF  # primitive index of "no primitive"


def vec3(v) -> Array3f:
    """A constant 3-vector, baked into the kernel as literals."""
    return Array3f(float(v[0]), float(v[1]), float(v[2]))


def opaque_u32(value: int) -> UInt32:
    """A run-time constant: changing it does not recompile the kernel. A scene's sizes and boxes enter the
    kernels so, not as literals: a new scene's first render then finds its kernels in Dr.Jit's cache."""
    return dr.opaque(UInt32, value)


FOLDED = (0.0, 1.0, -1.0)   # what opaque_f(..., fold=True) leaves literal: Dr.Jit folds x * 0 and x * 1 away


def opaque_f(value: float, fold: bool = False) -> Float:
    """A run-time constant Float (see opaque_u32); with `fold`, 0 and +-1 stay literals. For the linear parts
    of shapes' maps (normals, edges, frames' axes): an axis-aligned shape's zeros and ones then cost no
    arithmetic (the room's and the Cornell box's renders took 1.1-1.2x the CPU time with them read from
    memory), and the kernel depends on the shapes' orientations (which of those numbers are 0 or +-1), not on
    their other values. Positions, sizes and radiance are never folded: moving a light keeps the kernel."""
    value = float(value)
    return Float(value) if fold and value in FOLDED else dr.opaque(Float, value)


def opaque_vec3(v, fold: bool = False) -> Array3f:
    """A constant 3-vector as run-time constants (opaque_f): the same float values as vec3's literals, read
    by the kernel from memory, so that another scene's values run the same kernel."""
    return Array3f(*(opaque_f(c, fold) for c in (v[0], v[1], v[2])))


def segment_of(first, count: int):
    """The segment of each of `count` elements, for segments that start at elements `first` (ascending, the
    first 0; an unsigned Dr.Jit array, of any backend): a mark at each segment's start but the first one's,
    summed by an inclusive prefix sum."""
    kind = type(first)
    mark = dr.zeros(kind, count)
    dr.scatter(mark, 1, first, dr.arange(kind, dr.width(first)) > 0)
    return dr.prefix_reduce(dr.ReduceOp.Add, mark, exclusive=False)


def host_array(kind: type, a: np.ndarray, dtype=None):
    """`a`, flattened (in `dtype`, if given), as a host array of type `kind`, in memory starting on a cache
    line: Dr.Jit wraps a NumPy array's memory as it is, and a kernel reading it compiles anew for each
    alignment it finds. Copied only where needed."""
    a = np.asarray(a)
    if (dtype is not None and a.dtype != dtype) or not a.flags.c_contiguous or a.ctypes.data % 64:
        a = aligned(a, dtype)
    return kind(a.ravel())


def aligned(a: np.ndarray, dtype=None) -> np.ndarray:
    """A copy of `a` (flattened; in `dtype`, if given) starting on a 64-byte boundary (as aligned_zeros)."""
    out = aligned_zeros(a.shape, dtype or a.dtype)
    out[...] = a
    return out.ravel()


def aligned_zeros(shape: int | tuple[int, ...], dtype, alignment: int = 64) -> np.ndarray:
    """A C-contiguous array of zeros starting on an `alignment`-byte boundary. Dr.Jit wraps a NumPy
    array's memory as it is, and gathers from memory it finds unaligned as separate loads instead of
    packet loads."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    buffer = np.zeros(size + alignment, np.uint8)   # calloc: pages zeroed as first touched
    start = -buffer.ctypes.data % alignment
    return buffer[start:start + size].view(dtype).reshape(shape)


def packet_size(count: int) -> int:
    """The power of two at or above count: the values one packet load gathers. Dr.Jit gathers a packet only
    of a power of two values, from memory on a cache line, and anything else value by value; on the AMD EPYC
    this project is measured on, a render reading its primitive table value by value took 1.6x the CPU time
    of one reading it in packets (cornell_box.xml: 3.07 against 1.88 s), its material and texture tables up
    to 1.4x (textured_parameters.xml)."""
    return 1 << max(count - 1, 0).bit_length()


def row_buffer(shape: tuple[int, ...], k: int) -> np.ndarray:
    """Zeros (*shape, packet_size(k)) in Float's type on a cache line: rows of k values to fill in place
    ([..., :k]) and hand to host_array, as row_table does, without a copy of the unpadded rows."""
    return aligned_zeros((*shape, packet_size(k)), HOST_FLOAT)


def row_table(rows: np.ndarray):
    """Rows (..., k) as a Float table of rows of packet_size(k) values, zero-padded, on a cache line, so that
    gather_row reads a row in one packet load."""
    rows = np.asarray(rows)
    k = rows.shape[-1]
    out = row_buffer((rows.size // k,), k)
    out[:, :k] = rows.reshape(-1, k)
    return host_array(Float, out)


def gather_row(table, width: int, index, active=True, count: int | None = None) -> list:
    """The first `count` values (default all `width`) of row `index` of a row_table of rows `width` apart."""
    size = packet_size(width if count is None else count)
    x = dr.gather(ArrayXf, table, index * (width // size) if size < width else index, active,
                  shape=(size, dr.width(index)))
    return list(x)[:width if count is None else count]


def gather_vec3(table, index, active=True):
    """Row `index` of a row_table of 3-vectors, as an Array3f."""
    return Array3f(*gather_row(table, 4, index, active, 3))
