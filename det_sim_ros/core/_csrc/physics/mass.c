/*
 * The mass solves of the right-hand side (mass.h): a Cholesky solve of a small symmetric
 * positive definite block, each cell's inverted mass block (once per model) and the solve of a
 * one-cell group from it (Sherman-Morrison).
 */
#include <math.h>
#include <stdlib.h>

#include "physics/mass.h"

/* Solve Mt out = F for a small symmetric positive definite block (rows of stride ``ld``),
 * Cholesky in place. */
static void solve_spd(double *Mt, int64_t ld, const double *F, double *out, int64_t n)
{
    if (n == 1) {
        out[0] = F[0] / Mt[0];
        return;
    }
    for (int64_t j = 0; j < n; j++) {
        double s = Mt[j * ld + j];
        for (int64_t k = 0; k < j; k++)
            s -= Mt[j * ld + k] * Mt[j * ld + k];
        const double d = sqrt(s);
        Mt[j * ld + j] = d;
        for (int64_t i = j + 1; i < n; i++) {
            double t = Mt[i * ld + j];
            for (int64_t k = 0; k < j; k++)
                t -= Mt[i * ld + k] * Mt[j * ld + k];
            Mt[i * ld + j] = t / d;
        }
    }
    for (int64_t i = 0; i < n; i++) {
        double s = F[i];
        for (int64_t k = 0; k < i; k++)
            s -= Mt[i * ld + k] * out[k];
        out[i] = s / Mt[i * ld + i];
    }
    for (int64_t i = n - 1; i >= 0; i--) {
        double s = out[i];
        for (int64_t k = i + 1; k < n; k++)
            s -= Mt[k * ld + i] * out[k];
        out[i] = s / Mt[i * ld + i];
    }
}

/* The inverse of each cell's block of Mb into ``out`` (block rows like Mb), once per model:
 * the mass solve of a one-cell group needs no factorization per call (one_cell_solve).
 * Returns -1 when its scratch cannot be allocated. */
int ds_mass_inverse(const ds_model *m, double *out)
{
    const int64_t R = m->r_max;
    double *block = malloc(sizeof(double) * (size_t)(3 * R * R + 1));
    if (!block)
        return -1;
    double *unit = block + R * R, *column = unit + R * R;
    for (int64_t c = 0; c < m->n_cells; c++) {
        const int64_t o = m->cell[c].q0, r = m->cell[c].nr;
        for (int64_t k = 0; k < r; k++) {
            for (int64_t i = 0; i < r; i++) {
                for (int64_t j = 0; j < r; j++)
                    block[i * R + j] = m->Mb[(o + i) * R + j];
                unit[i] = i == k ? 1.0 : 0.0;
            }
            solve_spd(block, R, unit, column, r);
            for (int64_t i = 0; i < r; i++)
                out[(o + i) * R + k] = column[i];
        }
    }
    free(block);
    return 0;
}

/* Solve (Mb_c + mi J_c J_c') out = F_c for a cell alone in its group, mi its interface mass
 * (Sherman-Morrison with Mb_c^-1 from ds_mass_inverse): two products with Mb_c^-1 and one
 * division instead of a Cholesky factorization's chain of square roots and divisions. */
static void one_cell_solve(const ds_model *m, const ds_cell *cell, const double *J,
                           const double *F, double *out)
{
    const int64_t R = m->r_max, o = cell->q0, r = cell->nr;
    const double mi = cell->mi_self;   /* a one-cell group's only interface mass entry */
    double ja = 0.0, jb = 0.0, b_row[r];
    for (int64_t i = 0; i < r; i++) {
        const double *row = m->Mb_inv + (o + i) * R;
        double a = 0.0, b = 0.0;
        for (int64_t k = 0; k < r; k++) {
            a += row[k] * F[o + k];
            b += row[k] * J[o + k];
        }
        out[o + i] = a;
        b_row[i] = b;
        ja += J[o + i] * a;
        jb += J[o + i] * b;
    }
    const double scale = mi * ja / (1.0 + mi * jb);
    for (int64_t i = 0; i < r; i++)
        out[o + i] -= scale * b_row[i];
}

/* dqdot/dt into dx[n_q:2 n_q]: each group's mass solve (one-term models: one division). */
void ds_mass_solve(const ds_model *m, ds_work *w, double *dx)
{
    const int64_t nq = m->n_q, ld = m->mass_block;
    if (nq == 1) {
        dx[1] = w->F[0] / w->Mt[0];
        return;
    }
    for (int64_t c = 0; c < m->n_cells; c++) {
        const ds_cell *cell = &m->cell[c];
        const int64_t a = m->group_q[cell->group], b = m->group_q[cell->group + 1];
        if (ds_solved_alone(m, cell))
            one_cell_solve(m, cell, w->J, w->F, dx + nq);
        else if (cell->q0 == a)   /* a coupled group or a one-term cell: by its first cell */
            solve_spd(w->Mt + a * ld, ld, w->F + a, dx + nq + a, b - a);
    }
}
