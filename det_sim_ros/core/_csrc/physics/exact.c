/*
 * The exact kinematics' quadrature over one cell's nodes: most of a step's time at fidelity
 * exact (physics.c calls it from the right-hand side, the stiff rates and the outputs).
 *
 * sin(theta) = w' at each node: y = int 1 - cos(theta), h = qd' H_y qd = int w_t'^2 / cos^3,
 * J = dy/dq = int S' w' / cos, and the bending energy beyond EI int w''^2,
 * EI int w''^2 w'^2 / cos^2 with its gradient. Three passes over a cell's nodes (at most
 * DS_MAX_CELL_NODES), each a loop the compiler vectorizes across nodes: w', w_t' and w'' as
 * sums over the Ritz terms along the node-contiguous rows B1T, B2T; each node's terms with one
 * square root and one reciprocal; the sums over the nodes into J and F as interleaved dot
 * products along the same rows.
 */
#include <math.h>

#include "physics/exact.h"

/* With GCC on x86-64 glibc the two entry points are compiled twice, for AVX2 and for the
 * baseline, and the loader picks one for the machine: the same IEEE operations in the same
 * order on wider vectors (no reassociation, no fused multiply-add), so the same bits. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__GLIBC__)
#define WIDE_VECTORS __attribute__((target_clones("avx2", "default")))
#else
#define WIDE_VECTORS
#endif

/* Values of the cell's field at its nodes (w', w_t', w'': sums over the terms). */
typedef struct {
    double wp[DS_MAX_CELL_NODES], wd[DS_MAX_CELL_NODES], wpp[DS_MAX_CELL_NODES];
} node_fields;

/* Each node's contribution: to y, h and the bending energy, and the factors of its rows of
 * B1 (gy: into J; s1: into F) and of B2 (s2: into F). */
typedef struct {
    double y[DS_MAX_CELL_NODES], h[DS_MAX_CELL_NODES], bending[DS_MAX_CELL_NODES];
    double gy[DS_MAX_CELL_NODES], s1[DS_MAX_CELL_NODES], s2[DS_MAX_CELL_NODES];
} node_terms;

/* w', w_t' and w'' at nodes [0, n): sums over the terms j = 0 .. r - 1 in order
 * along the node-contiguous rows t1, t2 (row stride ``stride``). */
static inline void node_values(const double *restrict t1, const double *restrict t2,
                               int64_t stride, int64_t r, const double *restrict q,
                               const double *restrict qd, int64_t n, node_fields *restrict f)
{
    for (int64_t k = 0; k < n; k++) {
        f->wp[k] = t1[k] * q[0];
        f->wd[k] = t1[k] * qd[0];
        f->wpp[k] = t2[k] * q[0];
    }
    for (int64_t j = 1; j < r; j++) {
        const double *restrict r1 = t1 + j * stride, *restrict r2 = t2 + j * stride;
        const double qj = q[j], qdj = qd[j];
        for (int64_t k = 0; k < n; k++) {
            f->wp[k] += r1[k] * qj;
            f->wd[k] += r1[k] * qdj;
            f->wpp[k] += r2[k] * qj;
        }
    }
}

/* The node terms of nodes [0, n) from their fields, weights wt and 2 EI. */
static inline void exact_terms(const node_fields *restrict f, const double *restrict wt,
                               double EI2, int64_t n, node_terms *restrict t)
{
    for (int64_t k = 0; k < n; k++) {
        const double wp = f->wp[k], wpp = f->wpp[k], wp2 = wp * wp;
        const double cos2 = 1.0 - wp2, cs = sqrt(cos2);
        const double inv_cos2 = 1.0 / cos2, inv_cs = cs * inv_cos2;
        t->y[k] = wt[k] * (1.0 - cs);
        t->h[k] = wt[k] * f->wd[k] * f->wd[k] * inv_cos2 * inv_cs;
        t->gy[k] = wt[k] * wp * inv_cs;
        t->bending[k] = 0.5 * EI2 * wt[k] * wpp * wpp * wp2 * inv_cos2;
        t->s1[k] = EI2 * wt[k] * wpp * wpp * wp * inv_cos2 * inv_cos2;
        t->s2[k] = EI2 * wt[k] * wpp * wp2 * inv_cos2;
    }
}

/* sum_k a[k] b[k] for k < n as four interleaved partial sums (k mod 4), added in a fixed order:
 * four short dependency chains instead of one long one. */
static inline double dot4(const double *restrict a, const double *restrict b, int64_t n)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int64_t k = 0;
    for (; k + 3 < n; k += 4) {
        s0 += a[k] * b[k];
        s1 += a[k + 1] * b[k + 1];
        s2 += a[k + 2] * b[k + 2];
        s3 += a[k + 3] * b[k + 3];
    }
    for (; k < n; k++)
        s0 += a[k] * b[k];
    return (s0 + s1) + (s2 + s3);
}

/* J += sum_k gy_k S'(x_k) and, with F, F -= sum_k s1_k S'(x_k) + s2_k S''(x_k), along the
 * node-contiguous rows t1, t2. */
static inline void exact_sums(const double *restrict t1, const double *restrict t2,
                              int64_t stride, int64_t r, const node_terms *restrict t,
                              int64_t n, double *restrict J, double *restrict F)
{
    for (int64_t j = 0; j < r; j++) {
        const double *restrict r1 = t1 + j * stride, *restrict r2 = t2 + j * stride;
        J[j] += dot4(r1, t->gy, n);
        if (F)
            F[j] -= dot4(r1, t->s1, n) + dot4(r2, t->s2, n);
    }
}

WIDE_VECTORS ds_exact_sums ds_exact_cell(const ds_model *m, const ds_cell *cell,
                                         const double *q, const double *qd, double *J,
                                         double *F)
{
    const int64_t R = m->r_max, r = cell->nr, n = cell->g1 - cell->g0;
    const double *t1 = m->B1T + cell->g0 * R, *t2 = m->B2T + cell->g0 * R;
    ds_exact_sums sums = {0.0, 0.0, 0.0};
    node_fields f;
    node_terms t;
    node_values(t1, t2, n, r, q, qd, n, &f);
    exact_terms(&f, m->W + cell->g0, 2.0 * cell->EI, n, &t);
    for (int64_t k = 0; k < n; k++) {
        sums.y += t.y[k];
        sums.h += t.h[k];
        sums.bending += t.bending[k];
    }
    for (int64_t j = 0; j < r; j++)
        J[j] = 0.0;
    exact_sums(t1, t2, n, r, &t, n, J, F);
    return sums;
}

WIDE_VECTORS double ds_exact_shortening(const ds_model *m, const ds_cell *cell, const double *q)
{
    const int64_t R = m->r_max, r = cell->nr, n = cell->g1 - cell->g0;
    const double *t1 = m->B1T + cell->g0 * R, *wt = m->W + cell->g0;
    double wp[DS_MAX_CELL_NODES], y = 0.0;
    for (int64_t k = 0; k < n; k++)
        wp[k] = t1[k] * q[0];
    for (int64_t j = 1; j < r; j++)
        for (int64_t k = 0; k < n; k++)
            wp[k] += t1[j * n + k] * q[j];
    for (int64_t k = 0; k < n; k++)   /* the square roots as one vector loop */
        wp[k] = wt[k] * (1.0 - sqrt(1.0 - wp[k] * wp[k]));
    for (int64_t k = 0; k < n; k++)
        y += wp[k];
    return y;
}

void ds_transpose_nodes(const ds_model *m, const double *rows, double *out)
{
    const int64_t R = m->r_max;
    for (int64_t c = 0; c < m->n_cells; c++) {
        const int64_t g0 = m->cell[c].g0, n = m->cell[c].g1 - g0;
        for (int64_t k = 0; k < n; k++)
            for (int64_t j = 0; j < R; j++)
                out[g0 * R + j * n + k] = rows[(g0 + k) * R + j];
    }
}
