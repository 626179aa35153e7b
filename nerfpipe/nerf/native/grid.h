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

/* Instant-NGP's spatial hash of a vertex (Mueller et al. 2022, Eq. 4), as nerfpipe.nerf.fields.hash.hashed_corners
 * computes it in int64: (i * 1 xor j * 2654435761 xor k * 805459861) and (size - 1), size a power of two. */
static inline int64_t hashed_row(int64_t i, int64_t j, int64_t k, int64_t size) {
    return (int64_t)(((uint64_t)i ^ ((uint64_t)j * 2654435761ULL) ^ ((uint64_t)k * 805459861ULL)) & (uint64_t)(size - 1));
}

/* The trilinear corners of box coordinates u on one level, as nerfpipe.nerf.fields.grid.trilinear_corners computes
 * them (the same float operations in the same order): u clamped to [0, 1], p = u r, i = min(floor(p), r - 1),
 * f = p - i; corner c = 4 dx + 2 dy + dz at row offset + ((i + dx) n + j + dy) n + k + dz with n = r + 1 vertices
 * a side, weight (wx wy) wz of (1 - f) or f along each axis. (p >= 0, so its floor is its truncation.) A level of
 * ``size`` rows, fewer than its n^3 vertices, is hashed into them (hashed_row), as nerfpipe.nerf.fields.hash's. */
static inline void grid_corners(const float *u, int64_t resolution, int64_t offset, int64_t size, int64_t *rows,
                                float *weights) {
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
    if (size < n * n * n) {  /* hashed: its own loop, so that the dense one stays as tight as it was */
        for (int c = 0; c < 8; ++c) {
            const int dx = c >> 2, dy = (c >> 1) & 1, dz = c & 1;
            rows[c] = offset + hashed_row(i[0] + dx, i[1] + dy, i[2] + dz, size);
            weights[c] = (w[0][dx] * w[1][dy]) * w[2][dz];
        }
        return;
    }
    const int64_t base = (i[0] * n + i[1]) * n + i[2] + offset;
    for (int c = 0; c < 8; ++c) {
        const int dx = c >> 2, dy = (c >> 1) & 1, dz = c & 1;
        rows[c] = base + (dx * n + dy) * n + dz;
        weights[c] = (w[0][dx] * w[1][dy]) * w[2][dz];
    }
}

/* Whether every level fits a table of ``rows`` rows: level l of resolutions[l] >= 1 cells a side holds sizes[l] rows
 * from offsets[l], all (r + 1)^3 of its vertices or, hashed, a power of two fewer. */
static inline int levels_fit(const int64_t *resolutions, const int64_t *offsets, const int64_t *sizes, int64_t levels,
                             int64_t rows) {
    for (int64_t l = 0; l < levels; ++l) {
        if (resolutions[l] < 1 || resolutions[l] > 1 << 20 || offsets[l] < 0 || sizes[l] < 1) return 0;
        const int64_t n = resolutions[l] + 1, vertices = n * n * n;
        if (sizes[l] > vertices || (sizes[l] < vertices && (sizes[l] & (sizes[l] - 1))) || offsets[l] > rows - sizes[l])
            return 0;
    }
    return 1;
}

#endif
