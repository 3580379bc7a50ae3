#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>
#include <thread>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <system_error>
namespace nb = nanobind;
using u32 = uint32_t; using i64 = int64_t;
// the build's parameters (tracer/shapes/bvh_build.py's LEAF_SIZE, BINS, SAMPLES, TRAVERSAL_COST), passed in
struct Params { i64 leaf_size, bins, samples; double traversal_cost; };
constexpr i64 MAX_BINS = 64;
template <class T> static inline T mn(T a, T b) { return a < b ? a : b; }
template <class T> static inline T mx(T a, T b) { return a > b ? a : b; }
template <class T> using A = nb::ndarray<T, nb::c_contig, nb::device::cpu>;

template <class R>
static void keys_impl(const R *v, const i64 *f, i64 n, float *boxes, u32 *bits) {
    for (i64 t = 0; t < n; ++t)
        for (int a = 0; a < 3; ++a) {
            R x0 = v[3 * f[3 * t] + a], x1 = v[3 * f[3 * t + 1] + a], x2 = v[3 * f[3 * t + 2] + a];
            R lo = mn(mn(x0, x1), x2), hi = mx(mx(x0, x1), x2);
            float c = (float) ((lo + hi) / 2);
            if (c == 0) c = 0.f;
            u32 key; std::memcpy(&key, &c, 4);
            bits[a * n + t] = (key >> 31) ? ~key : key | 0x80000000u;
            boxes[6 * t + a] = (float) (-lo); boxes[6 * t + a + 3] = (float) hi;
        }
}
static void real_check(const nb::ndarray<nb::c_contig, nb::device::cpu> &v) {
    if (v.dtype() != nb::dtype<float>() && v.dtype() != nb::dtype<double>())
        throw std::invalid_argument("vertices: float32 or float64");
    if (v.ndim() != 2 || v.shape(1) != 3) throw std::invalid_argument("vertices: (m, 3)");
}
// faces (n, 3) of vertices [0, m): an index outside would read outside the vertices
static void faces_check(const A<i64> &f, size_t m) {
    if (f.ndim() != 2 || f.shape(1) != 3) throw std::invalid_argument("faces: (n, 3)");
    const i64 *p = f.data();
    for (size_t i = 0; i < 3 * f.shape(0); ++i)
        if (p[i] < 0 || (size_t) p[i] >= m) throw std::invalid_argument("faces: a vertex index outside the vertices");
}
static void triangle_keys(nb::ndarray<nb::c_contig, nb::device::cpu> v, A<i64> f, A<float> boxes, A<u32> bits) {
    real_check(v); faces_check(f, v.shape(0));
    i64 n = f.shape(0);
    if (boxes.ndim() != 2 || boxes.shape(0) != (size_t) n || boxes.shape(1) != 6 || bits.ndim() != 2
        || bits.shape(0) != 3 || bits.shape(1) != (size_t) n)
        throw std::invalid_argument("triangle_keys: boxes (n, 6), bits (3, n)");
    if (v.dtype() == nb::dtype<float>()) keys_impl((const float *) v.data(), f.data(), n, boxes.data(), bits.data());
    else keys_impl((const double *) v.data(), f.data(), n, boxes.data(), bits.data());
}

static inline double area(const float *b) {
    double x = (double) b[0] + (double) b[3], y = (double) b[1] + (double) b[4], z = (double) b[2] + (double) b[5];
    return 2 * (x * y + y * z + z * x);
}
static inline void merge(float *into, const float *b) { for (int c = 0; c < 6; ++c) into[c] = mx(into[c], b[c]); }

// The binned SAH split of slots [b, b + s) of the list along axis a: cost C + (A_l n_l + A_r n_r) / A and
// the left child's triangles, between bins of equal counts (MacDonald and Booth 1990; Wald 2007)
static void axis_split(const u32 *ids, const float *boxes, i64 a, i64 n, i64 b, i64 s, const Params &p,
                       double &cost, i64 &half) {
    const i64 BINS = p.bins, SAMPLES = p.samples;
    const float NINF = -std::numeric_limits<float>::infinity();
    float bin_box[MAX_BINS][6]; double suffix_area[MAX_BINS];
    i64 n_bins = std::min(s, BINS), q = std::min(s, SAMPLES); bool few = s < BINS, sampled = s > SAMPLES;
    const u32 *list = ids + a * n + b;
    for (i64 k = 0; k < n_bins; ++k) {
        i64 start = few ? k : q * k / BINS, end = few ? k + 1 : q * (k + 1) / BINS;
        float m[6] = {NINF, NINF, NINF, NINF, NINF, NINF};
        for (i64 i = start; i < end; ++i) merge(m, boxes + 6 * (i64) list[sampled ? i * s / SAMPLES : i]);
        std::memcpy(bin_box[k], m, sizeof m);
    }
    float merged[6] = {NINF, NINF, NINF, NINF, NINF, NINF};
    for (i64 k = n_bins - 1; k > 0; --k) { merge(merged, bin_box[k]); suffix_area[k] = area(merged); }
    for (int c = 0; c < 6; ++c) merged[c] = NINF;
    merge(merged, bin_box[0]);
    double best = std::numeric_limits<double>::infinity(); i64 h = 0;
    for (i64 k = 1; k < n_bins; ++k) {
        i64 n_left = few ? k : s * k / BINS;
        double c = (double) n_left * area(merged) + (double) (s - n_left) * suffix_area[k];
        c *= 1 + 1e-6 * (double) std::llabs(2 * n_left - s) / (double) s;
        if (k == 1 || c < best) { best = c; h = n_left; }
        merge(merged, bin_box[k]);
    }
    double whole = area(merged);
    cost = whole > 0 ? p.traversal_cost + best / whole : std::numeric_limits<double>::infinity();
    half = h;
}

// f(0), ..., f(tasks - 1), in contiguous shares over up to `threads` threads, this one among them; where a
// thread cannot be started, this one does its share (the results do not depend on who does which)
template <class F> static void parallel(i64 tasks, int threads, F &&f) {
    if (tasks <= 0) return;
    const int t = (int) std::min<i64>(std::max(threads, 1), tasks);
    auto share = [&](int j) { for (i64 i = tasks * j / t; i < tasks * (j + 1) / t; ++i) f(i); };
    std::vector<std::thread> pool;
    int started = 1;
    try {
        for (; started < t; ++started) pool.emplace_back(share, started);
    } catch (const std::system_error &) {}
    for (int j = started; j < t; ++j) share(j);
    share(0);
    for (auto &p : pool) p.join();
}

// The tree, level by level, over the lists `ids` (3, n) (partitioned in place) of triangles with boxes (n, 6)
static nb::tuple build_nodes(A<u32> ids_a, A<float> boxes_a, i64 leaf_size, i64 bins, i64 samples,
                             double traversal_cost, int threads) {
    if (bins < 2 || bins > MAX_BINS || samples < bins || leaf_size < 1)
        throw std::invalid_argument("build_nodes: bins in [2, 64], samples >= bins, leaf_size >= 1");
    if (ids_a.ndim() != 2 || ids_a.shape(0) != 3 || boxes_a.ndim() != 2 || boxes_a.shape(1) != 6
        || boxes_a.shape(0) != ids_a.shape(1))
        throw std::invalid_argument("build_nodes: ids (3, n), boxes (n, 6)");
    if (ids_a.shape(1) == 0) throw std::invalid_argument("build_nodes: no triangles");
    for (size_t i = 0; i < 3 * ids_a.shape(1); ++i)
        if (ids_a.data()[i] >= ids_a.shape(1)) throw std::invalid_argument("build_nodes: ids: a triangle outside the boxes");
    const Params p{leaf_size, bins, samples, traversal_cost}; const i64 SAMPLES = samples, LEAF_SIZE = leaf_size;
    u32 *ids = ids_a.data(); const float *boxes = boxes_a.data(); i64 n = ids_a.shape(1);
    std::vector<i64> left(2 * n, -1), right(2 * n, -1), first(2 * n, 0), count(2 * n, 0), levels;
    std::vector<uint8_t> side(n); std::vector<u32> spare(3 * n);
    std::vector<i64> begin{0}, size{n}, nb_, ns_;
    i64 n_nodes = 1;
    {
    nb::gil_scoped_release release;
    while (!begin.empty()) {
        i64 m = begin.size(), base = n_nodes - m;
        levels.push_back(base); levels.push_back(n_nodes);
        std::vector<i64> axis(m, 0), half(m); std::vector<double> cost(m, 0);
        for (i64 i = 0; i < m; ++i) half[i] = size[i] / 2;
        i64 work = 0; for (i64 i = 0; i < m; ++i) work += std::min(size[i], SAMPLES);
        int th = work > 20000 ? threads : 1;
        parallel(m, th, [&](i64 i) {
            if (size[i] <= 1) return;
            for (i64 a = 0; a < 3; ++a) {
                double c; i64 h; axis_split(ids, boxes, a, n, begin[i], size[i], p, c, h);
                if (a == 0 || c < cost[i]) { axis[i] = a; half[i] = h; cost[i] = c; }
            }
        });
        std::vector<i64> k;
        for (i64 i = 0; i < m; ++i) {
            bool split = size[i] > 1 && (size[i] > LEAF_SIZE || cost[i] < (double) size[i]);
            if (split) { left[base + i] = n_nodes + 2 * (i64) k.size(); right[base + i] = left[base + i] + 1; k.push_back(i); }
            else { first[base + i] = begin[i]; count[base + i] = size[i]; }
        }
        i64 moved = 0; for (i64 i : k) moved += size[i];
        int tp = moved > 20000 ? threads : 1;
        parallel(k.size(), tp, [&](i64 j) {
            i64 i = k[j], b = begin[i], s = size[i], a = axis[i], h = half[i];
            for (i64 x = b; x < b + h; ++x) side[ids[a * n + x]] = 0;
            for (i64 x = b + h; x < b + s; ++x) side[ids[a * n + x]] = 1;
        });
        parallel(3 * (i64) k.size(), tp, [&](i64 task) {
            i64 i = k[task / 3], a = task % 3, b = begin[i], s = size[i], h = half[i];
            if (a == axis[i]) return;
            u32 *list = ids + a * n, *sp = spare.data() + a * n;
            i64 l = b, r = b + h;
            for (i64 x = b; x < b + s; ++x) { u32 t = list[x]; if (side[t] == 0) list[l++] = t; else sp[r++] = t; }
            std::memcpy(list + b + h, sp + b + h, (s - h) * sizeof(u32));
        });
        nb_.assign(2 * k.size(), 0); ns_.assign(2 * k.size(), 0);
        for (size_t j = 0; j < k.size(); ++j) {
            i64 i = k[j];
            nb_[2 * j] = begin[i]; nb_[2 * j + 1] = begin[i] + half[i]; ns_[2 * j] = half[i]; ns_[2 * j + 1] = size[i] - half[i];
        }
        begin.swap(nb_); size.swap(ns_);
        n_nodes += begin.size();
    }
    }
    auto out = [&](std::vector<i64> &v, i64 len, std::vector<size_t> shape) {
        i64 *p = new i64[len]; std::memcpy(p, v.data(), len * sizeof(i64));
        nb::capsule owner(p, [](void *q) noexcept { delete[] (i64 *) q; });
        return nb::ndarray<nb::numpy, i64>(p, shape.size(), shape.data(), owner);
    };
    i64 L = levels.size() / 2;
    return nb::make_tuple(out(left, n_nodes, {(size_t) n_nodes}), out(right, n_nodes, {(size_t) n_nodes}),
                          out(first, n_nodes, {(size_t) n_nodes}), out(count, n_nodes, {(size_t) n_nodes}),
                          out(levels, 2 * L, {(size_t) L, 2}));
}

template <class R>
static void leaf_impl(const R *v, const i64 *f, const i64 *order, const i64 *first, const i64 *count, i64 m, R *lo, R *hi) {
    for (i64 i = 0; i < m; ++i)
        for (i64 j = first[i]; j < first[i] + count[i]; ++j) {
            i64 t = order[j];
            for (int a = 0; a < 3; ++a) {
                R x0 = v[3 * f[3 * t] + a], x1 = v[3 * f[3 * t + 1] + a], x2 = v[3 * f[3 * t + 2] + a];
                lo[3 * i + a] = mn(lo[3 * i + a], mn(mn(x0, x1), x2));
                hi[3 * i + a] = mx(hi[3 * i + a], mx(mx(x0, x1), x2));
            }
        }
}
static void leaf_boxes(nb::ndarray<nb::c_contig, nb::device::cpu> v, A<i64> f, A<i64> order, A<i64> first, A<i64> count,
                       nb::ndarray<nb::c_contig, nb::device::cpu> lo, nb::ndarray<nb::c_contig, nb::device::cpu> hi) {
    real_check(v); faces_check(f, v.shape(0));
    i64 m = first.shape(0), n = f.shape(0);
    if (lo.dtype() != v.dtype() || hi.dtype() != v.dtype()) throw std::invalid_argument("leaf_boxes: lo, hi of the vertices' type");
    if (count.shape(0) != (size_t) m || lo.ndim() != 2 || lo.shape(0) != (size_t) m || lo.shape(1) != 3
        || hi.ndim() != 2 || hi.shape(0) != (size_t) m || hi.shape(1) != 3 || order.shape(0) != (size_t) n)
        throw std::invalid_argument("leaf_boxes: first, count (m,), lo, hi (m, 3), order (n,)");
    for (i64 i = 0; i < m; ++i)
        if (first.data()[i] < 0 || count.data()[i] < 0 || first.data()[i] + count.data()[i] > n)
            throw std::invalid_argument("leaf_boxes: a leaf's slots outside the order");
    for (i64 j = 0; j < n; ++j)
        if (order.data()[j] < 0 || order.data()[j] >= n) throw std::invalid_argument("leaf_boxes: order: a triangle outside the faces");
    if (v.dtype() == nb::dtype<float>()) leaf_impl((const float *) v.data(), f.data(), order.data(), first.data(), count.data(), m, (float *) lo.data(), (float *) hi.data());
    else leaf_impl((const double *) v.data(), f.data(), order.data(), first.data(), count.data(), m, (double *) lo.data(), (double *) hi.data());
}

NB_MODULE(bvh_native, m) {
    m.def("triangle_keys", &triangle_keys);
    m.def("build_nodes", &build_nodes);
    m.def("leaf_boxes", &leaf_boxes);
}
