/* Two loops of training and rendering on the CPU that torch runs as many small operations.
 *
 * nerfpipe_scatter_bags, the grid fields' table gradient: out[bags[i, c]] += weights[i, c] * grad[i] for every bag i
 * (a point on one level) and corner c, the backward pass of the trilinear gather (nerfpipe/nerf/fields/grid.py).
 * torch's index_add_ first writes every corner's contribution to memory (points x levels x 8 rows of features) and
 * sorts the rows to add them in parallel; here one loop reads each bag once and adds its corners in place, in the
 * bags' order. On this project's 2-core machine: 3.6-4.1 ms where the products and index_add_ take 10.7 ms on one
 * thread and 7.3 on two (beer's 16,384 samples a step; their serial share, about 3.9 ms, bounds them on any number
 * of threads); two threads of this loop were slower than one, next to torch's own (docs/benchmarks.md).
 *
 * It returns how many corners named a row outside [0, rows); those are added nowhere.
 *
 * nerfpipe_contracted_steps, the steps of a march in contracted space (ContractedSpace.steps,
 * nerfpipe/nerf/spaces/ray_space.py): each step's length set at its start by the point's L-infinity norm in the
 * box's units, a sequence per ray that torch computes as a loop of eight operations over every ray for each step.
 *
 * Plain C: built in a second by the C compiler on the machine (nerfpipe/nerf/native/__init__.py), no torch headers. */
#include <math.h>
#include <stdint.h>

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
