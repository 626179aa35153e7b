/* nerfpipe_render_marched: rendering a dense grid field without gradients, one ray at a time from its march to its
 * colour, for every ray of a view (nerfpipe/nerf/fused.py says when it runs).
 *
 * torch renders a chunk of rays as some forty operations over arrays of samples: the march's candidate steps and
 * their cells (nerfpipe/nerf/samplers/march.py: march), the visibility pass a window of places at a time (visible),
 * the grid's features and the density MLP there, the colour MLP on the samples kept, and the compositing
 * (nerfpipe/nerf/render/volume.py: volume_render). Each writes its array to memory and reads it back, and the
 * visibility pass's bookkeeping is half of a render on a CPU. Here one function follows a ray: each occupied step's
 * point, its features (grid.h) and density, its weight, and the colour of the samples the ray reaches before its
 * transmittance falls below the early stop, summed as they come. Eight occupied steps at a time: their corner rows
 * asked of memory together, their MLPs evaluated two samples at a time (each weight read once for both). The same
 * quantities as torch's, computed in the same order along a ray, to float rounding (the optical depth before a
 * sample in double, as there); the MLPs' sums may be fused multiply-adds here.
 *
 * The same march serves training (nerfpipe_march_marched, at the file's end: nerfpipe/nerf/samplers/march.py's march
 * with a budget): each ray's occupied steps found as here, the sample at the ray's own random fraction into each, and
 * training's visibility pass (nerfpipe_reached_marched) the density alone along the samples kept.
 *
 * Rays are shared among OpenMP's threads (torch's own, see kernels.c); each ray's result is its own, so the threads
 * give the bits one thread gives. Built twice where the compiler can (GCC and clang's target_clones): for x86-64's
 * AVX2 with FMA, chosen at load time where the CPU has them, and for any x86-64. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#include "grid.h"

#if defined(__clang__)
#pragma clang fp contract(fast)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=fast")
#endif

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && !defined(__APPLE__) && !defined(NERFPIPE_NO_CLONES)
#define VECTOR_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define VECTOR_CLONES
#endif

#define MAX_WIDTH 1024       /* GridConfig.hidden's bound */
#define MAX_INPUTS 1024      /* features x levels (64 x 32 at most) and the colour MLP's inputs */
#define BLOCK_SAMPLES 8      /* occupied steps found, and their rows asked of memory, before the first is evaluated */
#define MAX_OPTICAL_DEPTH 1e4f
#define ACC_EPS 1e-10f

/* What a march over a dense grid field is made of (ctypes' MarchedGrid in nerfpipe/nerf/fused.py, field by field). */
typedef struct {
    int64_t contracted;          /* 1: ContractedSpace (steps grow beyond the box, points contracted); 0: BoxSpace */
    float center[3], half[3];    /* the contraction's scene box, as centre and half extent */
    float step;                  /* the march's step in field units: the occupancy grid's diagonal / steps */
    int64_t most;                /* steps a ray takes at most */
    double limit;                /* the optical depth at which a ray stops, -log(early_stop) (INFINITY: never) */
    const uint8_t *occupied;     /* (r^3,) the occupancy grid's cells, (i r + j) r + k */
    int64_t occupancy_resolution;
    float occupancy_lo[3], occupancy_hi[3];
    const float *table;          /* (rows, features): every level's vertices */
    int64_t rows, features, levels;
    const int64_t *resolutions, *offsets, *sizes;  /* sizes: each level's rows, fewer than its vertices where hashed */
    float lo[3], hi[3];          /* the field's box */
    int64_t hidden, geo, dir_freqs, view_dependent;
    /* the MLPs' weights and biases: density (features levels -> hidden -> 1 + geo), colour (geo [+ the direction's
     * encoding] -> hidden -> hidden -> 3); each weight transposed, (inputs, outputs), but the last, (3, hidden) */
    const float *w1, *b1, *w2, *b2, *w3, *b3, *w4, *b4, *w5, *b5;
} MarchedGrid;

/* y = x W + b for x (in,), W (in, out) row-major: out's sums run along x, as a matrix product's do; ReLU if asked.
 * For the common widths the sums are a constant number of vector registers, held there while x is read. */
typedef float v8 __attribute__((vector_size(32), aligned(4)));  /* eight floats, read and written anywhere */
typedef int32_t v8i __attribute__((vector_size(32), aligned(4)));
#define DENSE(OUT)                                                                                                   \
    static inline __attribute__((always_inline)) void dense_##OUT(const float *restrict w, const float *restrict b, \
                                                                  const float *restrict x, int64_t in,             \
                                                                  float *restrict y, int relu) {                   \
        v8 acc[OUT / 8];                                                                                             \
        for (int v = 0; v < OUT / 8; ++v) acc[v] = *(const v8 *)(b + 8 * v);                                         \
        for (int64_t i = 0; i < in; ++i) {                                                                           \
            const float xi = x[i];                                                                                   \
            const float *restrict wi = w + i * OUT;                                                                  \
            for (int v = 0; v < OUT / 8; ++v) acc[v] += xi * *(const v8 *)(wi + 8 * v);                              \
        }                                                                                                            \
        const v8 zero = {0};                                                                                         \
        for (int v = 0; v < OUT / 8; ++v) /* ReLU: the sum where it is positive, else +0 */                          \
            *(v8 *)(y + 8 * v) = relu ? (v8)((v8i)acc[v] & (acc[v] > zero)) : acc[v];                                \
    }
DENSE(16)
DENSE(32)
DENSE(64)

/* dense for two inputs x0 and x1 at once: each of W's rows read once for both, their sums in registers side by side
 * (16 or 32 outputs; other widths one input after the other). */
#define DENSE2(OUT)                                                                                                  \
    static inline __attribute__((always_inline)) void dense2_##OUT(                                                  \
        const float *restrict w, const float *restrict b, const float *restrict x0, const float *restrict x1,       \
        int64_t in, float *restrict y0, float *restrict y1, int relu) {                                              \
        v8 a0[OUT / 8], a1[OUT / 8];                                                                                 \
        for (int v = 0; v < OUT / 8; ++v) a0[v] = a1[v] = *(const v8 *)(b + 8 * v);                                 \
        for (int64_t i = 0; i < in; ++i) {                                                                           \
            const float p = x0[i], q = x1[i];                                                                        \
            const float *restrict wi = w + i * OUT;                                                                  \
            for (int v = 0; v < OUT / 8; ++v) {                                                                      \
                const v8 wv = *(const v8 *)(wi + 8 * v);                                                             \
                a0[v] += p * wv;                                                                                     \
                a1[v] += q * wv;                                                                                     \
            }                                                                                                        \
        }                                                                                                            \
        const v8 zero = {0};                                                                                         \
        for (int v = 0; v < OUT / 8; ++v) {                                                                          \
            *(v8 *)(y0 + 8 * v) = relu ? (v8)((v8i)a0[v] & (a0[v] > zero)) : a0[v];                                  \
            *(v8 *)(y1 + 8 * v) = relu ? (v8)((v8i)a1[v] & (a1[v] > zero)) : a1[v];                                  \
        }                                                                                                            \
    }
DENSE2(16)
DENSE2(32)

static inline __attribute__((always_inline)) void dense(const float *restrict w, const float *restrict b,
                                                        const float *restrict x, int64_t in, int64_t out,
                                                        float *restrict y, int relu) {
    switch (out) {
    case 16: dense_16(w, b, x, in, y, relu); return;
    case 32: dense_32(w, b, x, in, y, relu); return;
    case 64: dense_64(w, b, x, in, y, relu); return;
    }
    for (int64_t o = 0; o < out; ++o) y[o] = b[o];
    for (int64_t i = 0; i < in; ++i) {
        const float xi = x[i];
        const float *restrict wi = w + i * out;
        for (int64_t o = 0; o < out; ++o) y[o] += xi * wi[o];
    }
    if (relu)
        for (int64_t o = 0; o < out; ++o) y[o] = y[o] > 0.0f ? y[o] : 0.0f;
}

static inline __attribute__((always_inline)) void dense_pair(const float *restrict w, const float *restrict b,
                                                             const float *restrict x0, const float *restrict x1,
                                                             int64_t in, int64_t out, float *restrict y0,
                                                             float *restrict y1, int relu) {
    switch (out) {
    case 16: dense2_16(w, b, x0, x1, in, y0, y1, relu); return;
    case 32: dense2_32(w, b, x0, x1, in, y0, y1, relu); return;
    }
    dense(w, b, x0, in, out, y0, relu);
    dense(w, b, x1, in, out, y1, relu);
}

/* y = W x + b for the colour MLP's three outputs, W (3, in) as torch keeps it: three dot products along x. */
static inline __attribute__((always_inline)) void dense_rgb(const float *restrict w, const float *restrict b,
                                                            const float *restrict x, int64_t in, float *restrict y) {
    for (int o = 0; o < 3; ++o) {
        const float *restrict wo = w + o * in;
        v8 acc = {0};
        int64_t i = 0;
        for (; i + 8 <= in; i += 8) acc += *(const v8 *)(x + i) * *(const v8 *)(wo + i);
        float sum = b[o] + ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
        for (; i < in; ++i) sum += x[i] * wo[i];
        y[o] = sum;
    }
}

#define MIN(a, b) ((a) < (b) ? (a) : (b))  /* finite operands (the kernel refuses others): no library call */
#define MAX(a, b) ((a) > (b) ? (a) : (b))

/* The features of one point on every level (levels x features, level after level): the weighted sum of its corners'
 * rows (nerfpipe_grid_gather's, inlined with ``features`` a constant where it is one). */
static inline __attribute__((always_inline)) void gather(const float *restrict table, int64_t features, int64_t levels,
                                                         const int64_t *restrict rows, const float *restrict weights,
                                                         float *restrict out) {
    for (int64_t l = 0; l < levels; ++l) {
        float *f = out + l * features;
        for (int64_t j = 0; j < features; ++j) f[j] = 0.0f;
        for (int k = 0; k < 8; ++k) {
            const float *row = table + rows[8 * l + k] * features;
            const float w = weights[8 * l + k];
            for (int64_t j = 0; j < features; ++j) f[j] += w * row[j];
        }
    }
}

/* gather, with the common width of four features a constant. */
static inline __attribute__((always_inline)) void gather_point(const MarchedGrid *m, const int64_t *rows,
                                                               const float *weights, float *out) {
    if (m->features == 4) gather(m->table, 4, m->levels, rows, weights, out);
    else gather(m->table, m->features, m->levels, rows, weights, out);
}

/* Contraction (nerfpipe/nerf/spaces/contraction.py, Eq. 10 with the L-infinity norm) of a point in box units. */
static inline void contract(const float *x, float *y) {
    float n = MAX(MAX(fabsf(x[0]), fabsf(x[1])), fabsf(x[2]));
    if (n > 1.0f) {
        const float s = 2.0f - 1.0f / n;
        for (int a = 0; a < 3; ++a) y[a] = s * (x[a] / n);
    } else {
        for (int a = 0; a < 3; ++a) y[a] = x[a];
    }
}

/* Whether field point x lies in an occupied cell of the occupancy grid (OccupancyGrid.is_occupied). */
static inline int occupied(const MarchedGrid *m, const float *x) {
    const int64_t r = m->occupancy_resolution;
    int64_t index = 0;
    for (int a = 0; a < 3; ++a) {
        const float u = (x[a] - m->occupancy_lo[a]) / (m->occupancy_hi[a] - m->occupancy_lo[a]);
        if (!(u >= 0.0f && u <= 1.0f)) return 0;
        int64_t i = (int64_t)floorf(u * (float)r);
        i = i < 0 ? 0 : (i > r - 1 ? r - 1 : i);
        index = index * r + i;
    }
    return m->occupied[index] != 0;
}

/* Where a ray's march stands: its next step k, starting at t. */
typedef struct {
    int64_t k;
    float t, base;       /* base: the step in ray parameter inside the box (contracted) or everywhere (box) */
    float x0[3], dx[3];  /* the ray in box units (contracted) */
    int done;
} March;

/* The next occupied steps of a ray, up to ``capacity``: their t, start, end and field points. The steps as
 * ContractedSpace.steps (nerfpipe.nerf.native.contracted_steps) or constant_steps lay them, the sample half way
 * along each (march's u = 0.5). Its products and sums are not fused, as torch's are not: a point on a cell's face
 * falls in the cell torch puts it in. */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC push_options
#pragma GCC optimize("fp-contract=off")
#endif
/* The field point of o + t d: the ray's point (RayBatch.points), contracted (Contraction.to_field) or as it is. */
__attribute__((noinline)) static void field_point(const MarchedGrid *m, const float *o, const float *d, float t,
                                                  float *x) {
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    float p[3];
    for (int a = 0; a < 3; ++a) p[a] = o[a] + t * d[a];
    if (m->contracted) {
        for (int a = 0; a < 3; ++a) p[a] = (p[a] - m->center[a]) / m->half[a];
        contract(p, x);
    } else {
        for (int a = 0; a < 3; ++a) x[a] = p[a];
    }
}

/* A ray's march before its first step: the step in ray parameter, and in contracted space the ray in box units. */
__attribute__((noinline)) static March start_march(const MarchedGrid *m, const float *o, const float *d, float near) {
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    March s = {0, near, 0.0f, {0}, {0}, 0};
    if (m->contracted) {
        float norm = 0.0f;
        for (int a = 0; a < 3; ++a) {
            s.x0[a] = (o[a] - m->center[a]) / m->half[a];
            s.dx[a] = d[a] / m->half[a];
            norm += s.dx[a] * s.dx[a];
        }
        s.base = m->step / MAX(sqrtf(norm), 1e-12f);
    } else {
        s.base = m->step / MAX(sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), 1e-12f);
    }
    return s;
}

__attribute__((noinline)) static int next_samples(const MarchedGrid *m, March *s, const float *o, const float *d,
                                                  float near, float far, float u, int capacity, float *t_out,
                                                  float *start_out, float *end_out, float *x_out, int64_t *k_out) {
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
    int found = 0;
    while (!s->done && found < capacity) {
        if (s->k >= m->most) { s->done = 1; break; }
        float start, end;
        if (m->contracted) {
            start = s->t;
            const float n = MAX(MAX(fabsf(s->x0[0] + start * s->dx[0]), fabsf(s->x0[1] + start * s->dx[1])),
                                  fabsf(s->x0[2] + start * s->dx[2]));
            const float scale = MIN(MAX(n, 1.0f), 1e6f);
            end = MIN(start + s->base * (scale * scale), far);
        } else {
            start = MIN(near + (float)s->k * s->base, far);
            end = MIN(start + s->base, far);
        }
        if (!(start < far)) { s->done = 1; break; }
        s->t = end;
        s->k += 1;
        const float t = start + u * MAX(end - start, 0.0f);
        float x[3];
        field_point(m, o, d, t, x);
        if (!occupied(m, x)) continue;
        t_out[found] = t;
        start_out[found] = start;
        end_out[found] = end;
        if (x_out)
            for (int a = 0; a < 3; ++a) x_out[3 * found + a] = x[a];
        if (k_out) k_out[found] = s->k - 1;
        ++found;
    }
    return found;
}
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC pop_options
#endif

/* interval_stop_depths (nerfpipe/nerf/render/volume.py): the mean depth at which a ray stopping in [start, end] of
 * density sigma stops. */
static inline float stop_depth(float sigma, float start, float end) {
    const float length = MAX(end - start, 0.0f);
    const float tau = MIN(MAX(sigma, 0.0f), 1e30f) * length;
    float g;
    if (tau < 0.1f) g = 0.5f - tau / 12.0f + tau * tau * tau / 720.0f;
    else if (tau > 30.0f) g = 1.0f / tau;
    else g = 1.0f / tau - 1.0f / expm1f(tau);
    return start + length * g;
}

/* The direction's encoding the colour MLP reads (nerfpipe/nerf/fields/encoding.py: positional_encoding with its
 * input), into out; returns its width. */
static int64_t encode_direction(const float *v, int64_t freqs, float *out) {
    for (int a = 0; a < 3; ++a) out[a] = v[a];
    float scale = 1.0f;
    for (int64_t k = 0; k < freqs; ++k, scale *= 2.0f) {
        for (int a = 0; a < 3; ++a) {
            const float phase = fmodf(fmodf(v[a], 2.0f) * scale, 2.0f) * 3.14159265358979323846f;
            out[3 + 6 * k + a] = sinf(phase);
            out[3 + 6 * k + 3 + a] = cosf(phase);
        }
    }
    return 3 * (2 * freqs + 1);
}

/* The density MLP's outputs (out[q]: log density, then the colour's features) of ``found`` field points x: their corner
 * rows asked of memory together, then two points at a time (GridField._density before its activation); inside[q]: in
 * the field's box. */
static inline __attribute__((always_inline)) void block_densities(const MarchedGrid *m, const float *x, int found,
                                                                  int *inside, float (*out)[MAX_WIDTH + 1]) {
    const int64_t width = m->levels * m->features, hidden = m->hidden;
    int64_t corner_rows[BLOCK_SAMPLES][32 * 8];
    float corner_weights[BLOCK_SAMPLES][32 * 8];
    float features[MAX_INPUTS], features2[MAX_INPUTS], h1[MAX_WIDTH], h1b[MAX_WIDTH];
    for (int q = 0; q < found; ++q) {  /* every corner's row asked for before the first is read */
        float u[3];
        inside[q] = box_coordinates(x + 3 * q, m->lo, m->hi, u);
        if (u[0] != u[0] || u[1] != u[1] || u[2] != u[2]) {  /* a point that overflowed: outside, density 0, no rows */
            u[0] = u[1] = u[2] = 0.0f;
            inside[q] = 0;
        }
        for (int64_t l = 0; l < m->levels; ++l) {
            grid_corners(u, m->resolutions[l], m->offsets[l], m->sizes[l], corner_rows[q] + 8 * l, corner_weights[q] + 8 * l);
            for (int k = 0; k < 8; k += 2) __builtin_prefetch(m->table + corner_rows[q][8 * l + k] * m->features);
        }
    }
    for (int q = 0; q < found; q += 2) {
        const int r = q + 1 < found ? q + 1 : q;  /* a block of odd length evaluates its last twice */
        gather_point(m, corner_rows[q], corner_weights[q], features);
        gather_point(m, corner_rows[r], corner_weights[r], features2);
        dense_pair(m->w1, m->b1, features, features2, width, hidden, h1, h1b, 1);
        dense_pair(m->w2, m->b2, h1, h1b, hidden, 1 + m->geo, out[q], out[r], 0);
    }
}

/* One ray: its colour composited onto nothing (rgb), its depth and opacity (acc), as volume_render gives them; returns
 * how many samples it evaluated with colour (those it reached). */
VECTOR_CLONES
static int64_t render_ray(const MarchedGrid *m, const float *o, const float *d, const float *v, float near, float far,
                          float *rgb_out, float *depth_out, float *acc_out) {
    const int64_t hidden = m->hidden, geo = m->geo;
    float colour_bias[MAX_WIDTH];  /* the colour MLP's first layer on the direction, the same along the ray */
    for (int64_t h = 0; h < hidden; ++h) colour_bias[h] = m->b3[h];
    if (m->view_dependent) {
        float encoded[3 * (2 * 16 + 1)];
        const int64_t n = encode_direction(v, m->dir_freqs, encoded);
        for (int64_t i = 0; i < n; ++i)
            for (int64_t h = 0; h < hidden; ++h) colour_bias[h] += encoded[i] * m->w3[(geo + i) * hidden + h];
    }
    March s = start_march(m, o, d, near);
    double depth = 0.0;  /* optical depth so far */
    float rgb[3] = {0.0f, 0.0f, 0.0f}, acc = 0.0f, stops = 0.0f;
    int64_t evaluated = 0;
    float t[BLOCK_SAMPLES], start[BLOCK_SAMPLES], end[BLOCK_SAMPLES], x[3 * BLOCK_SAMPLES];
    int inside[BLOCK_SAMPLES];
    float h2[MAX_WIDTH], h2b[MAX_WIDTH], h3[MAX_WIDTH], h3b[MAX_WIDTH], c[3];
    float sigma[BLOCK_SAMPLES], weight[BLOCK_SAMPLES], out[BLOCK_SAMPLES][MAX_WIDTH + 1];
    while (depth < m->limit) {
        const int found = next_samples(m, &s, o, d, near, far, 0.5f, BLOCK_SAMPLES, t, start, end, x, NULL);
        if (!found) break;
        block_densities(m, x, found, inside, out);
        int reached = 0;
        for (int q = 0; q < found && depth < m->limit; ++q, ++reached) {  /* composited in order */
            sigma[q] = inside[q] ? expf(MIN(out[q][0], 15.0f)) : 0.0f;
            const float tau = MIN(sigma[q] * MAX(end[q] - start[q], 0.0f), MAX_OPTICAL_DEPTH);
            weight[q] = expf(-(float)depth) * -expm1f(-tau);
            acc += weight[q];
            stops += weight[q] * stop_depth(sigma[q], start[q], end[q]);
            depth += (double)tau;
        }
        for (int q = 0; q < reached; q += 2) {  /* the colour of the samples reached, two at a time */
            const int r = q + 1 < reached ? q + 1 : q;
            dense_pair(m->w3, colour_bias, out[q] + 1, out[r] + 1, geo, hidden, h2, h2b, 1);
            dense_pair(m->w4, m->b4, h2, h2b, hidden, hidden, h3, h3b, 1);
            dense_rgb(m->w5, m->b5, h3, hidden, c);
            for (int a = 0; a < 3; ++a) rgb[a] += weight[q] * (1.0f / (1.0f + expf(-c[a])));
            if (r == q) break;
            dense_rgb(m->w5, m->b5, h3b, hidden, c);
            for (int a = 0; a < 3; ++a) rgb[a] += weight[r] * (1.0f / (1.0f + expf(-c[a])));
        }
        evaluated += reached;
    }
    for (int a = 0; a < 3; ++a) rgb_out[a] = rgb[a];
    const float stopped = acc > ACC_EPS ? stops / acc : far;
    *depth_out = MIN(MAX(stopped, near), MAX(far, near));
    *acc_out = acc;
    return evaluated;
}

/* 0 where the kernels can take ``m`` and n rays (origins, directions, viewdirs (n, 3), and their near and far (n,)
 * where given, else NULL); -1 where a value is not finite or a size is out of bounds, -2 where the levels overrun the
 * table. */
static int64_t check_marched(const MarchedGrid *m, const float *origins, const float *directions,
                             const float *viewdirs, const float *near, const float *far, int64_t n) {
    if (!levels_fit(m->resolutions, m->offsets, m->sizes, m->levels, m->rows)) return -2;
    if (m->hidden < 1 || m->hidden > MAX_WIDTH || m->geo < 0 || m->geo + 1 > MAX_WIDTH || m->levels > 32
        || m->levels * m->features > MAX_INPUTS || m->dir_freqs < 0 || m->dir_freqs > 16 || m->occupancy_resolution < 1)
        return -1;
    for (int64_t r = 0; r < n; ++r) {  /* a sum of finite floats may overflow too: torch's operators then render */
        float all = near ? near[r] + far[r] : 0.0f;
        for (int c = 0; c < 3; ++c) all += origins[3 * r + c] + directions[3 * r + c] + viewdirs[3 * r + c];
        if (!isfinite(all)) return -1;
    }
    return 0;
}

/* Renders n rays (origins, directions, unit viewing directions (n, 3), near and far (n,)) into rgb (n, 3), depth and
 * acc (n,), each ray's evaluated samples into counts (n,). Returns -1, writing nothing, if an input is not finite or a
 * size is out of this kernel's bounds (torch's operators then render), -2 if the levels overrun the table. */
int64_t nerfpipe_render_marched(const MarchedGrid *m, const float *origins, const float *directions,
                                const float *viewdirs, const float *near, const float *far, int64_t n, float *rgb,
                                float *depth, float *acc, int64_t *counts, int64_t threads) {
    (void)threads;
    const int64_t checked = check_marched(m, origins, directions, viewdirs, near, far, n);
    if (checked) return checked;
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 64) num_threads(n >= 256 && threads > 1 ? (int)threads : 1)
#endif
    for (int64_t r = 0; r < n; ++r)
        counts[r] = render_ray(m, origins + 3 * r, directions + 3 * r, viewdirs + 3 * r, near[r], far[r], rgb + 3 * r,
                               depth + r, acc + r);
    return 0;
}

/* One ray's marched samples (count of them, their t, start and end): which it reaches before its optical depth passes
 * the early stop (keep), as nerfpipe.nerf.samplers.march.visible decides from the field's density. */
VECTOR_CLONES
static void reach_ray(const MarchedGrid *m, const float *o, const float *d, const float *t, const float *start,
                      const float *end, int64_t count, uint8_t *keep) {
    double depth = 0.0;
    float x[3 * BLOCK_SAMPLES], out[BLOCK_SAMPLES][MAX_WIDTH + 1];
    int inside[BLOCK_SAMPLES];
    for (int64_t j = 0; j < count; j += BLOCK_SAMPLES) {
        const int found = count - j < BLOCK_SAMPLES ? (int)(count - j) : BLOCK_SAMPLES;
        if (!(depth < m->limit)) {
            for (int64_t k = j; k < count; ++k) keep[k] = 0;
            return;
        }
        for (int q = 0; q < found; ++q) field_point(m, o, d, t[j + q], x + 3 * q);
        block_densities(m, x, found, inside, out);
        for (int q = 0; q < found; ++q) {
            keep[j + q] = depth < m->limit;
            if (!keep[j + q]) continue;
            const float sigma = inside[q] ? expf(MIN(out[q][0], 15.0f)) : 0.0f;
            depth += (double)MIN(sigma * MAX(end[j + q] - start[j + q], 0.0f), MAX_OPTICAL_DEPTH);
        }
    }
}

/* nerfpipe_reached_marched: of n_samples samples packed ray after ray (ray (n,), non-decreasing; t, starts, ends (n,))
 * of rays (origins, directions (rays, 3)), which each ray reaches before its transmittance falls below the early
 * stop, into keep (n,): training's visibility pass, without the colour. Returns -1, writing nothing, where an input is
 * not finite, a sample names no ray, or a size is out of bounds; -2 if the levels overrun the table. */
int64_t nerfpipe_reached_marched(const MarchedGrid *m, const float *origins, const float *directions, int64_t rays,
                                 const int64_t *ray, const float *t, const float *starts, const float *ends,
                                 int64_t n, uint8_t *keep, int64_t threads) {
    (void)threads;
    const int64_t checked = check_marched(m, origins, directions, directions, NULL, NULL, rays);
    if (checked) return checked;
    for (int64_t i = 0; i < n; ++i) {
        if (ray[i] < 0 || ray[i] >= rays || (i && ray[i] < ray[i - 1]) || !isfinite(t[i] + starts[i] + ends[i]))
            return -1;
    }
    /* where each ray's samples begin: rays without samples begin where the next does */
    int64_t *first = (int64_t *)malloc((size_t)(rays + 1) * sizeof(int64_t));
    if (!first) return -1;
    for (int64_t r = 0, i = 0; r <= rays; ++r) {
        while (i < n && ray[i] < r) ++i;
        first[r] = i;
    }
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 64) num_threads(n >= 4096 && threads > 1 ? (int)threads : 1)
#endif
    for (int64_t r = 0; r < rays; ++r)
        reach_ray(m, origins + 3 * r, directions + 3 * r, t + first[r], starts + first[r], ends + first[r],
                  first[r + 1] - first[r], keep + first[r]);
    free(first);
    return 0;
}

/* A growing list of marched samples: one thread's share of a march. */
typedef struct {
    float *t, *start, *end;
    int64_t *k, *ray;
    int64_t count, capacity;
    int failed;  /* memory ran out */
} Marched;

static int marched_reserve(Marched *list, int64_t more) {
    if (list->count + more <= list->capacity) return 1;
    int64_t capacity = list->capacity ? 2 * list->capacity : 4096;
    while (capacity < list->count + more) capacity *= 2;
    float *t = realloc(list->t, (size_t)capacity * sizeof(float));
    if (t) list->t = t;
    float *start = realloc(list->start, (size_t)capacity * sizeof(float));
    if (start) list->start = start;
    float *end = realloc(list->end, (size_t)capacity * sizeof(float));
    if (end) list->end = end;
    int64_t *k = realloc(list->k, (size_t)capacity * sizeof(int64_t));
    if (k) list->k = k;
    int64_t *ray = realloc(list->ray, (size_t)capacity * sizeof(int64_t));
    if (ray) list->ray = ray;
    if (!(t && start && end && k && ray)) return 0;
    list->capacity = capacity;
    return 1;
}

/* nerfpipe_march_marched: training's march (nerfpipe/nerf/samplers/march.py: march, then within_budget), each ray's
 * occupied steps found as rendering finds them (next_samples), the sample a fraction u[r] into each: of rays (origins,
 * directions (rays, 3), near and far (rays,)), the leading rays whose samples number at most ``budget`` together (at
 * least one), packed ray after ray into ray_out, t_out, start_out, end_out and the step k_out of each along its ray,
 * whose capacity must hold ``budget`` samples and one ray's most. Rays split among the threads in blocks, each thread's
 * samples in its own list, gathered in the rays' order after. Returns the samples written and the rays kept (in
 * *kept), -1 where an input is not finite (or memory ran out), the capacity is short or the march's sizes are out of
 * bounds. */
int64_t nerfpipe_march_marched(const MarchedGrid *m, const float *origins, const float *directions, const float *near,
                               const float *far, const float *u, int64_t rays, int64_t budget, int64_t capacity,
                               int64_t *ray_out, float *t_out, float *start_out, float *end_out, int64_t *k_out,
                               int64_t *kept, int64_t threads) {
    (void)threads;
    if (m->occupancy_resolution < 1 || m->most < 1 || capacity < budget + m->most || rays < 1) return -1;
    for (int64_t r = 0; r < rays; ++r) {
        float all = near[r] + far[r] + u[r];
        for (int c = 0; c < 3; ++c) all += origins[3 * r + c] + directions[3 * r + c];
        if (!isfinite(all)) return -1;
    }
    int64_t *counts = calloc((size_t)rays, sizeof(int64_t));
    int nthreads = 1;
#ifdef _OPENMP
    nthreads = rays >= 256 && threads > 1 ? (int)threads : 1;
#endif
    Marched *lists = calloc((size_t)nthreads, sizeof(Marched));
    int failed = !counts || !lists;
    if (!failed) {
#ifdef _OPENMP
#pragma omp parallel num_threads(nthreads)
#endif
        {
            int me = 0;
#ifdef _OPENMP
            me = omp_get_thread_num();
#endif
            Marched *list = lists + me;
            /* contiguous blocks of rays, so that each list holds its rays in order */
            const int64_t first = rays * me / nthreads, last = rays * (me + 1) / nthreads;
            for (int64_t r = first; r < last && !list->failed; ++r) {
                const float *o = origins + 3 * r, *d = directions + 3 * r;
                March s = start_march(m, o, d, near[r]);
                while (!s.done) {
                    if (!marched_reserve(list, BLOCK_SAMPLES)) {
                        list->failed = 1;
                        break;
                    }
                    const int64_t at = list->count;
                    const int found = next_samples(m, &s, o, d, near[r], far[r], u[r], BLOCK_SAMPLES, list->t + at,
                                                   list->start + at, list->end + at, NULL, list->k + at);
                    for (int q = 0; q < found; ++q) list->ray[at + q] = r;
                    list->count += found;
                    counts[r] += found;
                    if (!found) break;
                }
            }
        }
    }
    for (int me = 0; !failed && me < nthreads; ++me) failed = lists[me].failed;
    int64_t total = 0, taken = 0;
    if (!failed) {
        for (; taken < rays; ++taken) {  /* within_budget: at least one ray */
            if (taken && total + counts[taken] > budget) break;
            total += counts[taken];
        }
        int64_t written = 0;
        for (int me = 0; me < nthreads && written < total; ++me) {
            const Marched *list = lists + me;
            for (int64_t i = 0; i < list->count && written < total; ++i, ++written) {
                ray_out[written] = list->ray[i];
                t_out[written] = list->t[i];
                start_out[written] = list->start[i];
                end_out[written] = list->end[i];
                k_out[written] = list->k[i];
            }
        }
    }
    for (int me = 0; lists && me < nthreads; ++me) {
        free(lists[me].t);
        free(lists[me].start);
        free(lists[me].end);
        free(lists[me].k);
        free(lists[me].ray);
    }
    free(lists);
    free(counts);
    if (failed) return -1;
    *kept = taken;
    return total;
}
