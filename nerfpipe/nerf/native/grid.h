/* What the native kernels share: a point's place in a dense grid field's box and its trilinear corners on a level,
 * as nerfpipe.nerf.fields.grid computes them (kernels.c: the features and their gradient; render.c: rendering). */
#ifndef NERFPIPE_GRID_H
#define NERFPIPE_GRID_H

#include <stdint.h>

/* A point's coordinates in the box [lo, hi] as torch computes them, u = (x - lo) / (hi - lo), and whether it lies
 * inside (every u in [0, 1]). */
static inline int box_coordinates(const float *x, const float *lo, const float *hi, float *u) {
    int in = 1;
    for (int a = 0; a < 3; ++a) {
        u[a] = (x[a] - lo[a]) / (hi[a] - lo[a]);
        in &= (u[a] >= 0.0f) & (u[a] <= 1.0f);
    }
    return in;
}

/* The trilinear corners of box coordinates u on one level, as nerfpipe.nerf.fields.grid.trilinear_corners computes
 * them (the same float operations in the same order): u clamped to [0, 1], p = u r, i = min(floor(p), r - 1),
 * f = p - i; corner c = 4 dx + 2 dy + dz at row offset + ((i + dx) n + j + dy) n + k + dz with n = r + 1 vertices
 * a side, weight (wx wy) wz of (1 - f) or f along each axis. (p >= 0, so its floor is its truncation.) */
static inline void grid_corners(const float *u, int64_t resolution, int64_t offset, int64_t *rows, float *weights) {
    const float r = (float)resolution;
    const int64_t n = resolution + 1;
    float w[3][2];
    int64_t i[3];
    for (int a = 0; a < 3; ++a) {
        const float clamped = u[a] < 0.0f ? 0.0f : (u[a] > 1.0f ? 1.0f : u[a]);
        const float p = clamped * r;
        float cell = (float)(int64_t)p;
        cell = cell < r - 1.0f ? cell : r - 1.0f;
        const float f = p - cell;
        i[a] = (int64_t)cell;
        w[a][0] = 1.0f - f;
        w[a][1] = f;
    }
    const int64_t base = (i[0] * n + i[1]) * n + i[2] + offset;
    for (int c = 0; c < 8; ++c) {
        const int dx = c >> 2, dy = (c >> 1) & 1, dz = c & 1;
        rows[c] = base + (dx * n + dy) * n + dz;
        weights[c] = (w[0][dx] * w[1][dy]) * w[2][dz];
    }
}

#endif
