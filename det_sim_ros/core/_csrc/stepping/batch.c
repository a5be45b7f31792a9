/*
 * The whole model's control periods: independent coupled groups step one by one (or spread over
 * threads) in their own layout, gathered from and scattered back to the model's state; and
 * offline runs of many periods.
 *
 * The groups' results are combined in group order, so they do not depend on the number of
 * threads.
 */
#include <stdlib.h>
#include <string.h>

#include "stepping/batch.h"
#include "physics/outputs.h"
#include "physics/physics.h"
#include "stepping/kind.h"
#include "stepping/stepper.h"

/* Gather the group's part of the whole model's x into the local layout (energies start at 0:
 * the group adds what it books to the model's totals, see ds_period). */
static void gather(const ds_model *m, const ds_group *g, const double *x, double *xl)
{
    const ds_model *v = g->m;
    const int64_t nq = v->n_q, nc = v->n_cells;
    memcpy(xl, x + g->q_first, (size_t)nq * sizeof(double));
    memcpy(xl + nq, x + m->n_q + g->q_first, (size_t)nq * sizeof(double));
    if (m->creep)
        memcpy(xl + v->i_eps, x + m->i_eps + g->c_first, (size_t)nc * sizeof(double));
    if (m->rc_source)
        memcpy(xl + v->i_qp, x + m->i_qp + g->c_first, (size_t)nc * sizeof(double));
    if (m->amp_state)
        memcpy(xl + v->i_va, x + m->i_va + g->c_first, (size_t)nc * sizeof(double));
    if (m->power)
        xl[v->i_power] = xl[v->i_power + 1] = 0.0;
}

static void scatter(const ds_model *m, const ds_group *g, const double *xl, double *x)
{
    const ds_model *v = g->m;
    const int64_t nq = v->n_q, nc = v->n_cells;
    memcpy(x + g->q_first, xl, (size_t)nq * sizeof(double));
    memcpy(x + m->n_q + g->q_first, xl + nq, (size_t)nq * sizeof(double));
    if (m->creep)
        memcpy(x + m->i_eps + g->c_first, xl + v->i_eps, (size_t)nc * sizeof(double));
    if (m->rc_source)
        memcpy(x + m->i_qp + g->c_first, xl + v->i_qp, (size_t)nc * sizeof(double));
    if (m->amp_state)
        memcpy(x + m->i_va + g->c_first, xl + v->i_va, (size_t)nc * sizeof(double));
}

/*
 * One control period of the whole model with the input u held (u_old: the input of the last
 * period). Independent groups step one by one (or spread over ``threads``) in their own
 * layout; the state is written back only when every group succeeded, and the energies the
 * groups booked are added to the model's in group order (deterministic for any thread count).
 * On failure x is unchanged and the first failing group's status is returned.
 */
int ds_period(ds_stepper *st, double *x, const double *u_old, const double *u)
{
    const ds_model *m = st->model;
    if (st->n_groups == 1)
        return st->kind->period(st, &st->group[0], x, u_old, u);
    const int64_t n_groups = st->n_groups;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(st->threads) if (st->threads > 1)
#endif
    for (int64_t gi = 0; gi < n_groups; gi++) {
        ds_group *g = &st->group[gi];
        gather(m, g, x, g->x_local);
        g->status = st->kind->period(st, g, g->x_local, u_old + g->c_first,
                                     u + g->c_first);
    }
    for (int64_t gi = 0; gi < n_groups; gi++)
        if (st->group[gi].status != DS_OK)
            return st->group[gi].status;
    for (int64_t gi = 0; gi < n_groups; gi++) {
        const ds_group *g = &st->group[gi];
        scatter(m, g, g->x_local, x);
        if (m->power) {
            x[m->i_power] += g->x_local[g->m->i_power];
            x[m->i_power + 1] += g->x_local[g->m->i_power + 1];
        }
    }
    return DS_OK;
}

/*
 * Many control periods (offline runs): period k holds U[k]; X[k + 1] and Y[k + 1] receive the
 * state and the outputs after it. ``u_held`` is the input held now (already booked), ``u_last``
 * the one the last period ran with. Returns a status; *done = periods completed, and x is left at
 * the last good state. ``ow``: scratch for the outputs and the input-jump bookkeeping.
 */
static int run_serial(ds_stepper *st, ds_work *ow, double *x, const double *u_held,
                      const double *u_last, const double *U, int64_t n, double *X, double *Y,
                      int64_t *done)
{
    const ds_model *m = st->model;
    const int64_t nx = m->n_state, nu = m->n_cells, ny = ds_n_outputs(m);
    const double *u_book = u_held, *u_prev = u_last;
    int status = DS_OK;
    int64_t k;
    for (k = 0; k < n; k++) {
        const double *u = U + k * nu;
        ds_book_input_jump(m, x, u_book, u, ow);
        u_book = u;
        status = ds_period(st, x, u_prev, u);
        if (status != DS_OK)
            break;
        status = ds_outputs(m, x, u, Y + (k + 1) * ny, ow);
        if (status != DS_OK)
            break;
        memcpy(X + (k + 1) * nx, x, (size_t)nx * sizeof(double));
        u_prev = u;
    }
    *done = k;
    return status;
}

#define RUN_CHUNK 32   /* periods a thread runs its groups through between two joins */

/* Group gi's periods [c0, c1) from its local state: each state straight into its column of X,
 * the energies it booked into ``booked``; on failure, the period into failed_at[gi]. */
static void run_group_chunk(const ds_stepper *st, int64_t gi, int64_t c0, int64_t c1,
                            const double *u_last, const double *U, double *X, double *booked,
                            int64_t *failed_at)
{
    const ds_model *m = st->model;
    const int64_t nx = m->n_state, nu = m->n_cells;
    ds_group *g = &st->group[gi];
    for (int64_t j = c0; j < c1 && g->status == DS_OK; j++) {
        const double *u = U + j * nu + g->c_first;
        const double *u_old = (j == 0 ? u_last : U + (j - 1) * nu) + g->c_first;
        if (m->power)
            g->x_local[g->m->i_power] = g->x_local[g->m->i_power + 1] = 0.0;
        g->status = st->kind->period(st, g, g->x_local, u_old, u);
        if (g->status != DS_OK) {
            failed_at[gi] = j;
            break;
        }
        scatter(m, g, g->x_local, X + (j + 1) * nx);
        if (m->power) {
            double *b = booked + (gi * RUN_CHUNK + (j - c0)) * 2;
            b[0] = g->x_local[g->m->i_power];
            b[1] = g->x_local[g->m->i_power + 1];
        }
    }
}

/* Complete period k (the j-th of its chunk) with the input u, once every group ran it: the
 * energies the groups booked added in group order, the state into x, the outputs into Y[k + 1].
 * Returns the first failing group's status, or the outputs'. */
static int complete_period(const ds_stepper *st, ds_work *ow, double *x, const double *u,
                           int64_t k, int64_t j, const double *booked, const int64_t *failed_at,
                           double *X, double *Y)
{
    const ds_model *m = st->model;
    const int64_t nx = m->n_state, ny = ds_n_outputs(m);
    for (int64_t gi = 0; gi < st->n_groups; gi++)
        if (failed_at[gi] == k)
            return st->group[gi].status;
    double *row = X + (k + 1) * nx;
    double w_in = 0.0, w_diss = 0.0;
    if (m->power) {
        w_in = x[m->i_power];
        w_diss = x[m->i_power + 1];
        for (int64_t gi = 0; gi < st->n_groups; gi++) {
            const double *b = booked + (gi * RUN_CHUNK + j) * 2;
            w_in += b[0];
            w_diss += b[1];
        }
    }
    memcpy(x, row, (size_t)nx * sizeof(double));
    if (m->power) {
        x[m->i_power] = w_in;
        x[m->i_power + 1] = w_diss;
    }
    const int status = ds_outputs(m, x, u, Y + (k + 1) * ny, ow);
    if (status == DS_OK)
        memcpy(row, x, (size_t)nx * sizeof(double));
    return status;
}

/*
 * ds_run for independent groups on several threads without a join per period: each thread
 * runs its groups through RUN_CHUNK periods (states straight into their columns of X, the
 * energies each group books per period into ``booked``), then one thread completes those
 * periods in order: input-jump bookkeeping, energies added in group order, outputs. The
 * arithmetic is that of run_serial, so results are bit-identical for any thread count. One
 * thread runs this way too: a group's scratch stays in cache for its RUN_CHUNK periods instead
 * of every group's being walked once per period, which pays on large arrays (bench/batch.py).
 */
static int run_chunked(ds_stepper *st, ds_work *ow, double *x, const double *u_held,
                       const double *u_last, const double *U, int64_t n, double *X, double *Y,
                       int64_t *done)
{
    const ds_model *m = st->model;
    const int64_t nu = m->n_cells, n_groups = st->n_groups;
    double *booked = m->power ? malloc((size_t)(n_groups * RUN_CHUNK * 2) * sizeof(double))
                              : NULL;
    int64_t *failed_at = malloc((size_t)n_groups * sizeof(int64_t));
    if ((m->power && !booked) || !failed_at) {
        free(booked);
        free(failed_at);
        return run_serial(st, ow, x, u_held, u_last, U, n, X, Y, done);
    }
    for (int64_t gi = 0; gi < n_groups; gi++) {
        gather(m, &st->group[gi], x, st->group[gi].x_local);
        st->group[gi].status = DS_OK;
        failed_at[gi] = n;
    }
    const double *u_book = u_held;
    int status = DS_OK;
    int64_t k = 0;
    for (int64_t c0 = 0; c0 < n && status == DS_OK; c0 += RUN_CHUNK) {
        const int64_t c1 = c0 + RUN_CHUNK < n ? c0 + RUN_CHUNK : n;
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 8) num_threads(st->threads)
#endif
        for (int64_t gi = 0; gi < n_groups; gi++)
            run_group_chunk(st, gi, c0, c1, u_last, U, X, booked, failed_at);
        for (k = c0; k < c1; k++) {   /* complete the chunk's periods in order */
            const double *u = U + k * nu;
            ds_book_input_jump(m, x, u_book, u, ow);
            u_book = u;
            status = complete_period(st, ow, x, u, k, k - c0, booked, failed_at, X, Y);
            if (status != DS_OK)
                break;
        }
    }
    free(booked);
    free(failed_at);
    *done = k;
    return status;
}

int ds_run(ds_stepper *st, ds_work *ow, double *x, const double *u_held, const double *u_last,
           const double *U, int64_t n, double *X, double *Y, int64_t *done)
{
    const int64_t nx = st->model->n_state;
    memcpy(X, x, (size_t)nx * sizeof(double));
    const int status = st->n_groups > 1
                       ? run_chunked(st, ow, x, u_held, u_last, U, n, X, Y, done)
                       : run_serial(st, ow, x, u_held, u_last, U, n, X, Y, done);
    /* a failed period, or its outputs, leave x where the last good period ended (before the
     * failed period booked its input jump), whichever part failed */
    if (status != DS_OK)
        memcpy(x, X + *done * nx, (size_t)nx * sizeof(double));
    return status;
}
