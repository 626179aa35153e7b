/* Loops of training and rendering on the CPU that torch runs as many small operations.
 *
 * nerfpipe_scatter_bags, the grid fields' table gradient: out[bags[i, c]] += weights[i, c] * grad[i] for every bag i
 * (a point on one level) and corner c, the backward pass of the trilinear gather (nerfpipe/nerf/fields/grid.py).
 * torch's index_add_ first writes every corner's contribution to memory (points x levels x 8 rows of features) and
 * sorts the rows to add them in parallel; here one loop reads each bag once and adds its corners in place, in the
 * bags' order. On this project's 2-core machine: 3.6-4.1 ms where the products and index_add_ take 10.7 ms on one
 * thread and 7.3 on two (beer's 16,384 samples a step; their serial share, about 3.9 ms, bounds them on any number
 * of threads); two threads of this loop were slower than one, next to torch's own (docs/benchmarks.md).
 *
 * It returns how many corners named a row outside [0, rows); those are added nowhere. The hashed and plane fields
 * use it, and the dense grid where its points take a gradient (camera refinement).
 *
 * nerfpipe_grid_gather and nerfpipe_grid_scatter, the dense grid field's features and their backward pass, from the
 * points themselves: each point's corners made (the twenty-odd operations torch runs over arrays of points x levels
 * x 8), their rows asked of memory a block of points ahead and summed (or added to) at once, so that neither pass
 * writes or keeps the corners. With OpenMP (built with -fopenmp where the compiler has it; the runtime is then the
 * libgomp torch has loaded, so these run on torch's own threads, which wait for work between its operators) the
 * gather splits the points and the scatter the table's rows among the threads. On beer's 16,384 samples a step, with
 * a matrix product between calls as in training: 0.44 ms and 1.0 ms on two threads, 0.8 ms and 1.36 ms on one,
 * where torch's corners and embedding_bag take 2.2 ms (docs/benchmarks.md).
 *
 * nerfpipe_contracted_steps, the steps of a march in contracted space (ContractedSpace.steps,
 * nerfpipe/nerf/spaces/ray_space.py): each step's length set at its start by the point's L-infinity norm in the
 * box's units, a sequence per ray that torch computes as a loop of eight operations over every ray for each step.
 *
 * Plain C: built in a second by the C compiler on the machine (nerfpipe/nerf/native/__init__.py), no torch headers. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#include "grid.h"

int64_t nerfpipe_scatter_bags(float *out, int64_t rows, int64_t features, const int64_t *bags,
                              const float *weights, const float *grad, int64_t n, int64_t corners) {
    int64_t outside = 0;
    for (int64_t i = 0; i < n; ++i) {
        const float *g = grad + i * features;
        for (int64_t c = 0; c < corners; ++c) {
            const int64_t row = bags[i * corners + c];
            if (row < 0 || row >= rows) {
                ++outside;
                continue;
            }
            float *o = out + row * features;
            const float w = weights[i * corners + c];
            for (int64_t f = 0; f < features; ++f) o[f] += w * g[f];
        }
    }
    return outside;
}

/* Edges (rays, most + 1) of each ray's steps from near to far: t_0 = near, t_{k+1} = min(t_k + base * s^2, far)
 * with s the L-infinity norm of x0 + t_k dx clamped to [1, 1e6] (Contraction.step_scale_at). Returns how many steps
 * the longest ray took (at least 1, at most ``most``); every ray's edges are written that far, those after it
 * reached far repeating its last. Returns -1, writing nothing, if an input is not finite: torch's operators carry
 * NaN along a ray, as fminf and fmaxf here would not. */
int64_t nerfpipe_contracted_steps(const float *x0, const float *dx, const float *base, const float *near,
                                  const float *far, int64_t rays, int64_t most, float *edges, int64_t *counts) {
    for (int64_t r = 0; r < rays; ++r) {
        float all = base[r] + near[r] + far[r];
        for (int64_t a = 0; a < 3; ++a) all += x0[3 * r + a] + dx[3 * r + a];
        if (!isfinite(all)) return -1;  /* a sum of finite floats may overflow to inf too: then torch's loop runs */
    }
    int64_t longest = 1;
    const int64_t columns = most + 1;
    for (int64_t r = 0; r < rays; ++r) {
        float *e = edges + r * columns;
        float t = near[r];
        const float f = far[r], b = base[r];
        const float ox = x0[3 * r], oy = x0[3 * r + 1], oz = x0[3 * r + 2];
        const float vx = dx[3 * r], vy = dx[3 * r + 1], vz = dx[3 * r + 2];
        e[0] = t;
        int64_t k = 0;
        while (k < most) {
            const float n = fmaxf(fmaxf(fabsf(ox + t * vx), fabsf(oy + t * vy)), fabsf(oz + t * vz));
            const float s = fminf(fmaxf(n, 1.0f), 1e6f);
            t = fminf(t + b * (s * s), f);
            e[++k] = t;
            if (!(t < f)) break;
        }
        counts[r] = k;
        if (k > longest) longest = k;
    }
    for (int64_t r = 0; r < rays; ++r) {
        float *e = edges + r * columns;
        for (int64_t k = counts[r] + 1; k <= longest; ++k) e[k] = e[counts[r]];
    }
    return longest;
}

/* Whether this build runs its loops on OpenMP's threads (1) or on one (0). */
int64_t nerfpipe_openmp(void) {
#ifdef _OPENMP
    return 1;
#else
    return 0;
#endif
}

/* Whether no coordinate of the m points (m, 3) is NaN; the grid kernels below take only such points (torch's
 * operators fail on NaN, as a clamp here would not; infinities clamp to the box's faces both ways). */
static int no_nan(const float *x, int64_t m) {
    int nan = 0;
    for (int64_t q = 0; q < 3 * m; ++q) nan |= x[q] != x[q];
    return !nan;
}

/* The corners (rows and weights, points x levels x 8) of a block of up to BLOCK points from x, each row's cache line
 * (of those in [first_row, end_row)) asked for as it is made, so that the block's reads from the table (a random row each, mostly outside the cache)
 * are under way together before the first is summed; writes the points' inside flags if ``inside`` is given. */
#define BLOCK 16
static void block_corners(const float *x, int64_t count, const float *lo, const float *hi, const int64_t *resolutions,
                          const int64_t *offsets, const int64_t *sizes, int64_t levels, const float *table,
                          int64_t features, int64_t *rows, float *weights, uint8_t *inside, int64_t first_row,
                          int64_t end_row) {
    float u[3];
    for (int64_t q = 0; q < count; ++q) {
        const int in = box_coordinates(x + 3 * q, lo, hi, u);
        if (inside) inside[q] = (uint8_t)in;
        for (int64_t l = 0; l < levels; ++l) {
            int64_t *r = rows + (q * levels + l) * 8;
            grid_corners(u, resolutions[l], offsets[l], sizes[l], r, weights + (q * levels + l) * 8);
            for (int c = 0; c < 8; c += 2) {
                if (r[c] >= first_row && r[c] < end_row) __builtin_prefetch(table + r[c] * features);
            }
        }
    }
}

/* out[k] = sum_c weights[k, c] table[rows[k, c]] for n bags k of 8 corners (inlined with ``features`` a constant). */
static inline void sum_corners(const float *restrict table, int64_t features, const int64_t *restrict rows,
                               const float *restrict weights, int64_t n, float *restrict out) {
    for (int64_t k = 0; k < n; ++k) {
        float acc[64] = {0.0f};  /* features <= 64 (GridConfig's bounds) */
        for (int c = 0; c < 8; ++c) {
            const float *t = table + rows[8 * k + c] * features;
            const float w = weights[8 * k + c];
            for (int64_t f = 0; f < features; ++f) acc[f] += w * t[f];
        }
        for (int64_t f = 0; f < features; ++f) out[k * features + f] = acc[f];
    }
}

/* table[rows[k, c]] += weights[k, c] grad[k] for n bags k of 8 corners, the rows in [first_row, end_row) only. */
static inline void add_corners(float *restrict table, int64_t features, const int64_t *restrict rows,
                               const float *restrict weights, int64_t n, const float *restrict grad,
                               int64_t first_row, int64_t end_row) {
    for (int64_t k = 0; k < n; ++k) {
        const float *g = grad + k * features;
        for (int c = 0; c < 8; ++c) {
            const int64_t row = rows[8 * k + c];
            if (row < first_row || row >= end_row) continue;
            float *t = table + row * features;
            const float w = weights[8 * k + c];
            for (int64_t f = 0; f < features; ++f) t[f] += w * g[f];
        }
    }
}

/* nerfpipe_grid_gather, a grid field's features (nerfpipe.nerf.fields.grid.GridField.encode) in one pass: for each of
 * m points x (m, 3) and each of the levels, the sum over its 8 corners of weight x the table's row (features floats),
 * into out (m, levels, features); inside (m,) says whether the point lies in the box [lo, hi]. torch computes the
 * corners as some twenty operations over arrays of points x levels x 8 and gathers after; here the corners of a few
 * points at a time are made, their rows fetched together, and summed. Returns -1, writing nothing, if a coordinate
 * is NaN, -2 if the levels overrun the table (of ``rows`` rows). */
int64_t nerfpipe_grid_gather(const float *table, int64_t rows, int64_t features, const float *x, int64_t m,
                             const float *lo, const float *hi, const int64_t *resolutions, const int64_t *offsets,
                             const int64_t *sizes, int64_t levels, float *out, uint8_t *inside, int64_t threads) {
    (void)threads;  /* without OpenMP: one thread */
    if (!levels_fit(resolutions, offsets, sizes, levels, rows)) return -2;
    if (!no_nan(x, m)) return -1;
    const int64_t blocks = (m + BLOCK - 1) / BLOCK;
#ifdef _OPENMP
#pragma omp parallel num_threads(blocks >= 512 && threads > 1 ? (int)threads : 1)
#endif
    {
        int64_t first = 0, last = blocks;
#ifdef _OPENMP
        const int64_t t = omp_get_thread_num(), n = omp_get_num_threads();
        first = blocks * t / n;
        last = blocks * (t + 1) / n;
#endif
        int64_t rows[BLOCK * levels * 8];
        float weights[BLOCK * levels * 8];
        for (int64_t b = first; b < last; ++b) {
            const int64_t start = b * BLOCK, count = m - start < BLOCK ? m - start : BLOCK;
            block_corners(x + 3 * start, count, lo, hi, resolutions, offsets, sizes, levels, table, features, rows,
                          weights, inside + start, 0, INT64_MAX);
            switch (features) {  /* the feature loop unrolled for the common widths */
            case 2: sum_corners(table, 2, rows, weights, count * levels, out + start * levels * 2); break;
            case 4: sum_corners(table, 4, rows, weights, count * levels, out + start * levels * 4); break;
            case 8: sum_corners(table, 8, rows, weights, count * levels, out + start * levels * 8); break;
            default: sum_corners(table, features, rows, weights, count * levels, out + start * levels * features);
            }
        }
    }
    return 0;
}

/* The first row of the share ``t`` of ``n`` threads of a scatter over the levels: the levels laid end to end, each
 * one unit long (every point adds 8 corners on each, however many rows it has), cut into n equal lengths, a cut
 * within a level falling at the same fraction of its rows. */
static int64_t share_start(int64_t t, int64_t n, const int64_t *offsets, const int64_t *sizes, int64_t levels) {
    if (t >= n) return INT64_MAX;
    const int64_t whole = levels * t / n;  /* levels before the cut; the cut's fraction of the next: */
    const int64_t part = levels * t % n;
    if (whole >= levels) return INT64_MAX;
    return offsets[whole] + sizes[whole] * part / n;
}

/* nerfpipe_grid_scatter, its backward pass: table_grad[row] += weight x grad (m, levels, features) over every point,
 * level and corner, the corners made again from x as nerfpipe_grid_gather made them. On ``threads`` > 1 threads each
 * adds into its own range of rows (share_start), every thread making every point's corners: no two write the same
 * row, and each row receives its additions in the points' order, as on one thread. Returns -1, writing nothing, if a
 * coordinate is NaN, -2 if the levels overrun the table. */
int64_t nerfpipe_grid_scatter(float *table_grad, int64_t rows, int64_t features, const float *x, int64_t m,
                              const float *lo, const float *hi, const int64_t *resolutions, const int64_t *offsets,
                              const int64_t *sizes, int64_t levels, const float *grad, int64_t threads) {
    (void)threads;
    if (!levels_fit(resolutions, offsets, sizes, levels, rows)) return -2;
    if (!no_nan(x, m)) return -1;
#ifdef _OPENMP
#pragma omp parallel num_threads(m >= 8192 && threads > 1 ? (int)threads : 1)
#endif
    {
        int64_t t = 0, n = 1;
#ifdef _OPENMP
        t = omp_get_thread_num();
        n = omp_get_num_threads();
#endif
        const int64_t first_row = t == 0 ? 0 : share_start(t, n, offsets, sizes, levels);
        const int64_t end_row = t == n - 1 ? INT64_MAX : share_start(t + 1, n, offsets, sizes, levels);
        int64_t rows[BLOCK * levels * 8];
        float weights[BLOCK * levels * 8];
        for (int64_t start = 0; start < m; start += BLOCK) {
            const int64_t count = m - start < BLOCK ? m - start : BLOCK;
            block_corners(x + 3 * start, count, lo, hi, resolutions, offsets, sizes, levels, table_grad, features,
                          rows, weights, NULL, first_row, end_row);
            const float *g = grad + start * levels * features;
            switch (features) {
            case 2: add_corners(table_grad, 2, rows, weights, count * levels, g, first_row, end_row); break;
            case 4: add_corners(table_grad, 4, rows, weights, count * levels, g, first_row, end_row); break;
            case 8: add_corners(table_grad, 8, rows, weights, count * levels, g, first_row, end_row); break;
            default: add_corners(table_grad, features, rows, weights, count * levels, g, first_row, end_row);
            }
        }
    }
    return 0;
}
