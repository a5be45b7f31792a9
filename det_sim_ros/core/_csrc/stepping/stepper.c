/*
 * A stepper's set-up: one ds_group per coupled group (a model view with local indices when the
 * model has several), each group's scratch laid out in one arena, in group order.
 */
#include <stdlib.h>
#include <string.h>

#include "stepping/stepper.h"
#include "physics/physics.h"
#include "stepping/coupling.h"
#include "stepping/linear_part.h"
#include "stepping/kind.h"

/* Whether a group's charge couples exactly to its amplifier outputs (coupling.c). */
static int coupled(const ds_group *g, const ds_method *me)
{
    return g->m->amp_state && g->m->rc_source && ds_coupling_fits(me);
}

/* Doubles of a group's stepping scratch (without its rhs scratch). */
static int64_t group_size(const ds_group *g, const ds_method *me)
{
    const int64_t nx = g->m->n_state, s = me->n_stages, nt = me->n_terms;
    const int64_t n_phis = (me->n_args > 0 ? me->n_args : 1) * (me->k_max + 1);
    const int64_t n_cpl = coupled(g, me) ? g->m->n_cells * ds_coupling_size(me) : 0;
    return s * nx + 8 * nx + (s + 1) * nx + n_phis + nt * nx + n_cpl;
}

/* Lay a group's scratch out in ``mem`` (group_size + ds_work_size doubles, zeroed). */
static void group_attach(ds_group *g, const ds_method *me, double *mem)
{
    const int64_t nx = g->m->n_state, s = me->n_stages, nt = me->n_terms;
    const int64_t n_phis = (me->n_args > 0 ? me->n_args : 1) * (me->k_max + 1);
    g->N = mem;
    g->X = g->N + s * nx;
    g->L = g->X + nx;
    g->x_start = g->L + nx;
    g->pend = g->x_start + nx;
    g->x0 = g->pend + nx;
    g->x_keep = g->x0 + nx;
    g->inv_scale = g->x_keep + nx;
    g->x_local = g->inv_scale + nx;
    g->e_c = g->x_local + nx;
    g->phis = g->e_c + (s + 1) * nx;
    g->coef = g->phis + n_phis;
    g->cpl = coupled(g, me) ? g->coef + nt * nx : NULL;
    ds_work_attach(&g->w, g->m, g->coef + nt * nx
                                + (g->cpl ? g->m->n_cells * ds_coupling_size(me) : 0));
    for (int64_t k = 0; k < (s + 1) * nx; k++)
        g->e_c[k] = 1.0;
    for (int64_t t = 0; t < nt; t++)
        for (int64_t k = 0; k < nx; k++)
            g->coef[t * nx + k] = me->coef0[t];
    const ds_model *m = g->m;
    g->s0 = 2 * m->n_q + m->n_cells * m->creep;
    g->s1 = g->s0 + (me->exponential && m->rc_source ? m->n_cells * (1 + m->amp_state) : 0);
    g->quasi_static = me->exponential && m->rc_source;
}

/* The sizes, offsets and arrays of the view *v (a copy of the whole model m) of the group
 * with coordinates [a, b) and cells [c0, c1). */
static void view_arrays(ds_model *v, const ds_model *m, int64_t a, int64_t b, int64_t c0,
                        int64_t c1)
{
    v->n_q = b - a;
    v->n_cells = c1 - c0;
    v->n_groups = 1;
    v->n_structure = 0;
    v->P = NULL;
    v->mass_block = b - a;
    v->i_eps = 2 * v->n_q;
    v->i_qp = v->i_eps + v->n_cells * v->creep;
    v->i_va = v->i_qp + v->n_cells * v->rc_source;
    v->i_power = v->i_va + v->n_cells * v->amp_state;
    v->n_state = v->i_power + 2 * v->power;
    const int64_t g0 = m->cell[c0].g0;
    v->n_nodes = m->cell[c1 - 1].g1 - g0;
    v->B1 = m->B1 + g0 * m->r_max;
    v->B2 = m->B2 + g0 * m->r_max;
    v->B1T = m->B1T + g0 * m->r_max;
    v->B2T = m->B2T + g0 * m->r_max;
    v->W = m->W + g0;
    v->Mb = m->Mb + a * m->r_max;
    v->Mb_inv = m->Mb_inv + a * m->r_max;
    v->K = m->K + a * m->r_max;
    v->D = m->D + a * m->r_max;
    v->ref = m->ref + a;
    v->det = m->det + c0;
}

/* The view's own tables (g->view_cells, view_ints, view_mi): its cells, group offsets and
 * interface mass entries with local indices. */
static int view_tables(ds_group *g, const ds_model *m, int64_t gi, int64_t c0, int64_t c1)
{
    ds_model *v = &g->view;
    const int64_t g0 = m->cell[c0].g0, a = m->group_q[gi];
    int64_t n_mi = 0;
    for (int64_t e = 0; e < m->n_mi; e++)
        n_mi += m->cell[m->mi_row[e]].group == gi;
    v->n_mi = n_mi;
    g->view_cells = calloc((size_t)v->n_cells, sizeof(ds_cell));
    g->view_ints = calloc((size_t)(2 * n_mi + 2), sizeof(int64_t));
    g->view_mi = calloc((size_t)(n_mi + 1), sizeof(double));
    if (!g->view_cells || !g->view_ints || !g->view_mi)
        return -1;
    for (int64_t c = c0; c < c1; c++) {
        ds_cell cell = m->cell[c];
        cell.q0 -= a;
        cell.g0 -= g0;
        cell.g1 -= g0;
        cell.group = 0;
        g->view_cells[c - c0] = cell;
    }
    v->cell = g->view_cells;
    v->one_term = v->n_cells == 1 && v->cell[0].nr == 1 && v->cell[0].kinematics != KIN_EXACT;
    v->group_q = g->view_ints;
    v->group_q[0] = 0;
    v->group_q[1] = v->n_q;
    v->mi_row = g->view_ints + 2;
    v->mi_col = v->mi_row + n_mi;
    int64_t k = 0;
    for (int64_t e = 0; e < m->n_mi; e++) {
        if (m->cell[m->mi_row[e]].group != gi)
            continue;
        v->mi_row[k] = m->mi_row[e] - c0;
        v->mi_col[k] = m->mi_col[e] - c0;
        g->view_mi[k] = m->mi_val[e];
        k++;
    }
    v->mi_val = g->view_mi;
    return 0;
}

/* The model of group ``gi``: views into the whole model's arrays, indices made local. */
static int make_view(ds_group *g, const ds_model *m, int64_t gi)
{
    const int64_t a = m->group_q[gi], b = m->group_q[gi + 1];
    int64_t c0 = -1, c1 = -1;
    for (int64_t c = 0; c < m->n_cells; c++) {
        if (m->cell[c].group == gi) {
            if (c0 < 0)
                c0 = c;
            c1 = c + 1;
        }
    }
    g->view = *m;
    view_arrays(&g->view, m, a, b, c0, c1);
    if (view_tables(g, m, gi, c0, c1) < 0)
        return -1;
    g->m = &g->view;
    g->q_first = a;
    g->c_first = c0;
    return 0;
}

void ds_stepper_free(ds_stepper *st)
{
    for (int64_t i = 0; st->group && i < st->n_groups; i++) {
        ds_group *g = &st->group[i];
        free(g->view_cells);
        free(g->view_ints);
        free(g->view_mi);
        free(g->transient);
        st->kind->group_free(g);
    }
    free(st->group);
    st->group = NULL;
    free(st->arena);
    st->arena = NULL;
    ds_method_free(&st->method);
}

int ds_stepper_init(ds_stepper *st, const ds_model *m, double dt, double z_tol, double fine,
                    const ds_control *ctl, const double *inv_scale)
{
    st->model = m;
    st->dt = dt;
    st->z_tol = z_tol;
    st->fine = fine;
    st->threads = 1;
    st->n_groups = m->n_groups;
    st->group = calloc((size_t)m->n_groups, sizeof(ds_group));
    if (!st->group)
        return -1;
    /* the groups' models first, then all their scratch in one arena, in group order: a batch
     * period walks the groups in that order */
    int64_t total = 0;
    for (int64_t gi = 0; gi < m->n_groups; gi++) {
        ds_group *g = &st->group[gi];
        if (m->n_groups == 1) {
            g->m = (ds_model *)m;
        } else if (make_view(g, m, gi) < 0) {
            return -1;
        }
        total += group_size(g, &st->method) + ds_work_size(g->m);
    }
    st->arena = calloc((size_t)total, sizeof(double));
    if (!st->arena)
        return -1;
    double *next = st->arena;
    for (int64_t gi = 0; gi < m->n_groups; gi++) {
        ds_group *g = &st->group[gi];
        group_attach(g, &st->method, next);
        next += group_size(g, &st->method) + ds_work_size(g->m);
        g->ctl = g->ctl_initial = *ctl;
        if (g->m->amp) {   /* the DETs' transients in an amplified period (amp_period.c) */
            g->transient = calloc((size_t)g->m->n_cells, sizeof(ds_amp_transient));
            if (!g->transient)
                return -1;
        }
        /* the error norm's weights in the group's layout (only q, qdot are in the norm) */
        const int64_t nq = g->m->n_q;
        for (int64_t k = 0; k < nq; k++) {
            g->inv_scale[k] = inv_scale[g->q_first + k];
            g->inv_scale[nq + k] = inv_scale[m->n_q + g->q_first + k];
        }
        const int rc = st->kind->group_init(st, g);
        if (rc < 0)
            return rc;
    }
    st->options.weights = NULL;
    return 0;
}

void ds_reset_control(ds_stepper *st)
{
    for (int64_t gi = 0; gi < st->n_groups; gi++) {
        st->group[gi].ctl = st->group[gi].ctl_initial;
        st->group[gi].est = 0.0;
        st->kind->group_reset(&st->group[gi]);
    }
}
