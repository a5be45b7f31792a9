/*
 * The one stepping core: exponential Runge-Kutta schemes declared as coefficient tables
 * (det_sim_ros/sim/integrators.py), the charge transient after an input jump, the per-period
 * step-count controller and batch stepping of independent groups.
 *
 * Every decision depends only on the state and the inputs, so runs are bit-identical run to
 * run, and a group's result does not depend on the number of threads.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "detsim.h"

#define CTL_SAFETY 0.5   /* aim the next period's estimate at half the local tolerance */

/* phi_k(z) = sum_m z^m / (m + k)!, the exponential integrators' functions (phi_0 = e^z). */
static double phi(int64_t k, double z)
{
    if (k == 0)
        return exp(z);
    if (fabs(z) < 0.5) {   /* Taylor series: 18 terms reach round-off for |z| < 0.5, k >= 1 */
        double term = 1.0;
        for (int64_t m = 1; m <= k; m++)
            term /= (double)m;
        double s = term;
        for (int64_t m = 1; m < 18; m++) {
            term *= z / (double)(m + k);
            s += term;
        }
        return s;
    }
    double value = exp(z), fact = 1.0;
    for (int64_t m = 0; m < k; m++) {
        if (m > 0)
            fact *= (double)m;
        value = (value - 1.0 / fact) / z;
    }
    return value;
}

/* out[k] = phi_k(z) for k = 0..n-1 with one exp (or none) per call.
 * |z| < 0.5: phi_{n-1} from its Taylor series (18 terms reach round-off), then the downward
 * recurrence phi_{k-1} = z phi_k + 1/(k-1)!, which damps errors (|z| < 1) and needs no
 * division; else the upward recurrence phi_k = (phi_{k-1} - 1/(k-1)!) / z from exp(z). */
static void phi_all(double z, double *out, int64_t n)
{
    static const double inv[] = {1.0, 1.0, 1.0 / 2, 1.0 / 3, 1.0 / 4, 1.0 / 5, 1.0 / 6,
                                 1.0 / 7, 1.0 / 8, 1.0 / 9, 1.0 / 10, 1.0 / 11, 1.0 / 12,
                                 1.0 / 13, 1.0 / 14, 1.0 / 15, 1.0 / 16, 1.0 / 17, 1.0 / 18,
                                 1.0 / 19, 1.0 / 20, 1.0 / 21, 1.0 / 22, 1.0 / 23, 1.0 / 24,
                                 1.0 / 25, 1.0 / 26, 1.0 / 27, 1.0 / 28};
    if (fabs(z) < 0.5 && n >= 2 && n <= 10) {
        const int64_t k = n - 1;
        double term = 1.0;   /* 1/k! */
        for (int64_t m = 2; m <= k; m++)
            term *= inv[m];
        double inv_fact[10];
        inv_fact[0] = 1.0;
        for (int64_t m = 1; m <= k; m++)
            inv_fact[m] = inv_fact[m - 1] * inv[m];
        double s = term;
        for (int64_t m = 1; m < 18; m++) {
            term *= z * inv[m + k];
            s += term;
        }
        out[k] = s;
        for (int64_t j = k; j > 0; j--)
            out[j - 1] = z * out[j] + inv_fact[j - 1];
        if (n > 1)
            out[0] = exp(z);   /* phi_0 itself: exact exp, not the recurrence's */
        return;
    }
    if (fabs(z) < 0.5) {
        for (int64_t k = 0; k < n; k++)
            out[k] = phi(k, z);
        return;
    }
    out[0] = exp(z);
    double fact = 1.0;
    for (int64_t k = 1; k < n; k++) {
        out[k] = (out[k - 1] - 1.0 / fact) / z;
        fact *= (double)k;
    }
}

void ds_method_free(ds_method *me)
{
    free(me->c);
    free(me->term_stage);
    memset(me, 0, sizeof(*me));
}

/*
 * Decode a table: ``terms`` rows (stage row i, or n_stages for b; stage j; phi index k, -1 for
 * a constant weight; c_arg; weight), sorted by row. ``embedded``: e_0..e_s of the error
 * estimate h sum_j e_j N_j (e_s multiplies f(x_new)), or none (n_embedded = 0).
 */
int ds_method_init(ds_method *me, const double *c, int64_t s, const double *terms, int64_t nt,
                   const double *embedded, int64_t n_embedded)
{
    memset(me, 0, sizeof(*me));
    me->n_stages = s;
    me->n_terms = nt;
    /* one allocation per type */
    me->c = calloc((size_t)(s + 3 * nt + 2 + (s + 1) * s + (s + 2) + 64), sizeof(double));
    me->term_stage = calloc((size_t)(7 * nt + 3 * (s + 2) + 8), sizeof(int64_t));
    if (!me->c || !me->term_stage) {
        ds_method_free(me);
        return -1;
    }
    me->term_weight = me->c + s;
    me->args = me->term_weight + nt;
    me->coef0 = me->args + nt + 1;
    me->merged_weight = me->coef0 + nt;
    me->embedded = me->merged_weight + (s + 1) * s;
    me->term_phi = me->term_stage + nt;
    me->term_arg = me->term_phi + nt;
    me->row_start = me->term_arg + nt;
    me->ec_arg = me->row_start + (s + 2);
    me->merged_start = me->ec_arg + (s + 2);
    me->merged_stage = me->merged_start + (s + 2);
    me->exp_term = me->merged_stage + 2 * nt + 8;
    me->exp_phi_at = me->exp_term + nt;
    memcpy(me->c, c, (size_t)s * sizeof(double));
    int64_t n_args = 0, k_max = 0;
    for (int64_t t = 0; t < nt; t++) {
        const double *row = terms + 5 * t;
        me->term_stage[t] = (int64_t)row[1];
        me->term_phi[t] = (int64_t)row[2];
        me->term_weight[t] = row[4];
        int64_t found = -1;
        for (int64_t a = 0; a < n_args; a++)
            if (me->args[a] == row[3])
                found = a;
        if (found < 0) {
            me->args[n_args] = row[3];
            found = n_args++;
        }
        me->term_arg[t] = found;
        if (me->term_phi[t] > k_max)
            k_max = me->term_phi[t];
        if (me->term_phi[t] >= 0)
            me->exponential = 1;
    }
    me->n_args = n_args;
    me->k_max = k_max;
    /* the terms whose weight follows the stiff rate, and where their phi_k(c_arg z) lies in the
     * step's phis (args x (k_max + 1)) */
    for (int64_t t = 0; t < nt; t++) {
        if (me->term_phi[t] < 0)
            continue;
        me->exp_term[me->n_exp_terms] = t;
        me->exp_phi_at[me->n_exp_terms] = me->term_arg[t] * (k_max + 1) + me->term_phi[t];
        me->n_exp_terms++;
    }
    /* terms are grouped by stage row: row i uses row_start[i] .. row_start[i + 1] */
    for (int64_t t = 0; t < nt; t++)
        me->row_start[(int64_t)terms[5 * t] + 1] = t + 1;
    for (int64_t i = 1; i < s + 2; i++)
        if (me->row_start[i] < me->row_start[i - 1])
            me->row_start[i] = me->row_start[i - 1];
    /* exp(c_i z) and exp(z) are phi_0 of a table argument when one is equal (-1: compute) */
    for (int64_t i = 0; i < s + 1; i++) {
        const double ci = i < s ? c[i] : 1.0;
        me->ec_arg[i] = -1;
        for (int64_t a = 0; a < n_args; a++)
            if (me->args[a] == ci)
                me->ec_arg[i] = a;
    }
    /* L = 0 values: phi_k(0) = 1/k! */
    double phis0[64];
    phi_all(0.0, phis0, k_max + 1 < 64 ? k_max + 1 : 64);
    for (int64_t t = 0; t < nt; t++)
        me->coef0[t] = me->term_weight[t] * (me->term_phi[t] < 0 ? 1.0 : phis0[me->term_phi[t]]);
    /* The same table at L = 0, terms of equal (row, stage) merged and zeros dropped: what the
     * states without a stiff rate use (Krogstad's 16 terms are classical RK4's 7 there). */
    double *w0 = calloc((size_t)((s + 1) * s), sizeof(double));
    if (!w0) {
        ds_method_free(me);
        return -1;
    }
    for (int64_t t = 0; t < nt; t++)
        w0[(int64_t)terms[5 * t] * s + me->term_stage[t]] += me->coef0[t];
    int64_t n_m = 0;
    for (int64_t i = 0; i < s + 1; i++) {
        for (int64_t j = 0; j < s; j++) {
            if (w0[i * s + j] != 0.0) {
                me->merged_stage[n_m] = j;
                me->merged_weight[n_m] = w0[i * s + j];
                n_m++;
            }
        }
        me->merged_start[i + 1] = n_m;
    }
    free(w0);
    /* the error estimate needs stage 0 at the step's start (c_0 = 0) for its FSAL term */
    me->n_embedded = (n_embedded == s + 1 && c[0] == 0.0) ? n_embedded : 0;
    memcpy(me->embedded, embedded, (size_t)me->n_embedded * sizeof(double));
    return 0;
}

/* Doubles of a group's stepping scratch (without its rhs scratch). */
static int64_t group_size(const ds_group *g, const ds_method *me)
{
    const int64_t nx = g->m->n_state, s = me->n_stages, nt = me->n_terms;
    const int64_t n_phis = (me->n_args > 0 ? me->n_args : 1) * (me->k_max + 1);
    return s * nx + 8 * nx + (s + 1) * nx + n_phis + nt * nx;
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
    ds_work_attach(&g->w, g->m, g->coef + nt * nx);
    for (int64_t k = 0; k < (s + 1) * nx; k++)
        g->e_c[k] = 1.0;
    for (int64_t t = 0; t < nt; t++)
        for (int64_t k = 0; k < nx; k++)
            g->coef[t * nx + k] = me->coef0[t];
    const ds_model *m = g->m;
    g->s0 = 2 * m->n_q + m->n_cells * m->creep;
    g->s1 = g->s0 + (me->exponential && m->rc_source ? m->n_cells : 0);
    g->quasi_static = me->exponential && m->rc_source;
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
    ds_model *v = &g->view;
    *v = *m;
    v->n_q = b - a;
    v->n_cells = c1 - c0;
    v->n_groups = 1;
    v->n_structure = 0;
    v->P = NULL;
    v->mass_block = b - a;
    v->i_eps = 2 * v->n_q;
    v->i_qp = v->i_eps + v->n_cells * v->creep;
    v->i_power = v->i_qp + v->n_cells * v->rc_source;
    v->n_state = v->i_power + 2 * v->power;
    const int64_t g0 = m->cell[c0].g0;
    v->n_nodes = m->cell[c1 - 1].g1 - g0;
    v->B1 = m->B1 + g0 * m->r_max;
    v->B2 = m->B2 + g0 * m->r_max;
    v->W = m->W + g0;
    v->Mb = m->Mb + a * m->r_max;
    v->K = m->K + a * m->r_max;
    v->D = m->D + a * m->r_max;
    v->ref = m->ref + a;
    v->det = m->det + c0;
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
    v->group_q[1] = b - a;
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
    g->m = v;
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
    }
    free(st->group);
    st->group = NULL;
    free(st->arena);
    st->arena = NULL;
    ds_method_free(&st->method);
}

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
        /* the error norm's weights in the group's layout (only q, qdot are in the norm) */
        const int64_t nq = g->m->n_q;
        for (int64_t k = 0; k < nq; k++) {
            g->inv_scale[k] = inv_scale[g->q_first + k];
            g->inv_scale[nq + k] = inv_scale[m->n_q + g->q_first + k];
        }
    }
    return 0;
}

void ds_reset_control(ds_stepper *st)
{
    for (int64_t gi = 0; gi < st->n_groups; gi++) {
        st->group[gi].ctl = st->group[gi].ctl_initial;
        st->group[gi].est = 0.0;
    }
}

/*
 * Advance x (in the group's layout) in place by n_steps steps with the input u held.
 *
 * An exponential Runge-Kutta scheme for x' = L x + N(x) with the diagonal L of the stiff
 * charge rates frozen per step,
 *     X_i = phi_0(c_i h L) x + h sum_j a_ij(hL) N(X_j),  x+ = phi_0(hL) x + h sum_i b_i(hL) N(X_i)
 * where each a_ij, b_i is a sum of weight * phi_k(c_arg h L); with L = 0 (explicit methods, or
 * no stiff state) it is the classical Runge-Kutta method of the table. Exponential methods
 * integrate the charge in quasi-static coordinates z = q_p - C(q) v_inf: z is the small lag
 * behind the charge the circuit relaxes to, so the part of the charge equation left to the
 * explicit stages acts on z instead of on the full charge (a tiny frozen-L splitting error).
 * Step k has size h growth^k (graded steps after a charge transient). With an embedded table
 * the largest weighted error estimate of these steps is max'ed into g->est (one extra rhs at
 * the end for the last step's first-same-as-last term). On failure x holds the start state.
 */
static inline __attribute__((always_inline)) int
advance_core(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
             int64_t n_steps, double growth, const int64_t nx, const int64_t s,
             const int64_t s0, const int64_t s1)
{
    const ds_method *me = &st->method;
    const ds_model *m = g->m;
    const int64_t nmech = 2 * m->n_q, n_emb = me->n_embedded, kp = me->k_max + 1;
    const double *emb = me->embedded;
    double *N = g->N, *X = g->X, *L = g->L, *e_c = g->e_c, *pend = g->pend;
    double *phis = g->phis, *coef = g->coef;
    const int qs = g->quasi_static;
    for (int64_t k = 0; k < nx; k++)
        if (!isfinite(x[k]))
            return DS_NON_FINITE;
    memcpy(g->x_start, x, (size_t)nx * sizeof(double));
    if (qs)
        ds_shift_charge(m, x, u, -1.0, &g->w);
    int status = DS_OK;
    double h_prev = 0.0;
    for (int64_t step = 0; step < n_steps; step++) {
        status = ds_stiff_rates(m, x, L, &g->w, (int)me->exponential);
        if (status != DS_OK)
            break;
        for (int64_t k = s0; k < s1; k++) {
            const double z = h * L[k];
            for (int64_t a = 0; a < me->n_args; a++)
                phi_all(me->args[a] * z, phis + a * kp, kp);
            for (int64_t e = 0; e < me->n_exp_terms; e++) {
                const int64_t t = me->exp_term[e];
                coef[t * nx + k] = me->term_weight[t] * phis[me->exp_phi_at[e]];
            }
            for (int64_t i = 0; i < s + 1; i++) {
                const int64_t a = me->ec_arg[i];
                const double ci = i < s ? me->c[i] : 1.0;
                e_c[i * nx + k] = ci == 0.0 ? 1.0 : (a >= 0 ? phis[a * kp] : exp(ci * z));
            }
        }
        /* rows 0..s-1 of the table build the stages, row s (the weights b) the new state */
        for (int64_t i = 0; i < s + 1; i++) {
            memcpy(X, x, (size_t)nx * sizeof(double));
            for (int64_t t = me->merged_start[i]; t < me->merged_start[i + 1]; t++) {
                const double *Nj = N + me->merged_stage[t] * nx;
                const double wt = h * me->merged_weight[t];
                for (int64_t k = 0; k < s0; k++)
                    X[k] += wt * Nj[k];
                for (int64_t k = s1; k < nx; k++)
                    X[k] += wt * Nj[k];
            }
            for (int64_t k = s0; k < s1; k++) {   /* per state: the sum stays in a register */
                double acc = e_c[i * nx + k] * x[k];
                for (int64_t t = me->row_start[i]; t < me->row_start[i + 1]; t++)
                    acc += h * coef[t * nx + k] * N[me->term_stage[t] * nx + k];
                X[k] = acc;
            }
            if (i == s)
                break;
            double *Ni = N + i * nx;
            status = ds_rhs(m, X, u, Ni, &g->w, qs);
            if (status != DS_OK)
                break;
            for (int64_t k = s0; k < s1; k++)
                Ni[k] -= L[k] * X[k];
            if (i == 0 && h_prev > 0.0) {   /* FSAL: N_0 = f(x) completes the last estimate */
                for (int64_t k = 0; k < nmech; k++) {
                    const double e = fabs(h_prev * (pend[k] + emb[s] * N[k])) * g->inv_scale[k];
                    if (e > g->est)
                        g->est = e;
                }
            }
        }
        if (status != DS_OK)
            break;
        for (int64_t k = 0; k < nx; k++)
            if (!isfinite(X[k]))
                status = DS_NON_FINITE;
        if (status != DS_OK)
            break;
        memcpy(x, X, (size_t)nx * sizeof(double));
        if (n_emb > 0) {
            for (int64_t k = 0; k < nmech; k++) {
                double acc = 0.0;
                for (int64_t j = 0; j < s; j++)
                    acc += emb[j] * N[j * nx + k];
                pend[k] = acc;
            }
            h_prev = h;
        }
        h *= growth;
    }
    if (status == DS_OK && h_prev > 0.0) {   /* the last step's FSAL term: one more rhs */
        status = ds_rhs(m, x, u, N, &g->w, qs);
        for (int64_t k = 0; k < nmech; k++) {
            const double e = fabs(h_prev * (pend[k] + emb[s] * N[k])) * g->inv_scale[k];
            if (e > g->est)
                g->est = e;
        }
    }
    if (status != DS_OK) {
        memcpy(x, g->x_start, (size_t)nx * sizeof(double));
        return status;
    }
    g->steps += (double)n_steps;
    if (qs)
        ds_shift_charge(m, x, u, 1.0, &g->w);
    return DS_OK;
}

/* The layouts that batch runs and the default scene step (a one-term cell with creep and an RC
 * source, with or without the power monitor, under a four-stage table such as ETDRK4 or RK4)
 * get their own copy of the core with the sizes as constants, so the compiler unrolls the
 * per-state and per-stage loops and inlines the copies. The arithmetic and its order are the
 * generic core's (no -ffast-math, no contraction): the results are bit-identical. */
int ds_advance(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
               int64_t n_steps, double growth)
{
    const int64_t nx = g->m->n_state, s = st->method.n_stages, s0 = g->s0, s1 = g->s1;
    if (s == 4 && s0 == 3 && s1 == 4) {
        if (nx == 6)
            return advance_core(st, g, x, u, h, n_steps, growth, 6, 4, 3, 4);
        if (nx == 4)
            return advance_core(st, g, x, u, h, n_steps, growth, 4, 4, 3, 4);
    }
    return advance_core(st, g, x, u, h, n_steps, growth, nx, s, s0, s1);
}

/*
 * After an input jump, how long the charge transient stays above z_tol (C): *T (0 when no
 * transient matters), the shortest charge time constant *tau_min (s) and the largest input
 * jump *jump (V).
 *
 * A jump du moves the charge the circuit relaxes to by dz = C du Rp/(Rs+Rp); the lag decays
 * like dz exp(-t/tau) with tau = C (Rs || Rp). While it is large it changes the electrostatic
 * force on the time scale tau, which explicit mechanics stages with steps >> tau cannot follow
 * (measured: at 1 ms / 8 steps this alone made the 'step' error 1.9e-3; resolved, 8.6e-6).
 */
static void charge_transient(const ds_stepper *st, ds_group *g, const double *x,
                             const double *u_old, const double *u_new, double *T,
                             double *tau_min, double *jump)
{
    const ds_model *m = g->m;
    *T = 0.0;
    *tau_min = INFINITY;
    *jump = 0.0;
    int any = 0;
    for (int64_t i = 0; i < m->n_cells; i++)
        any |= u_new[i] != u_old[i];
    if (!any)
        return;
    double *lam = g->w.Us4;   /* free between rhs calls */
    ds_stretches(m, x, &g->w, lam);
    for (int64_t i = 0; i < m->n_cells; i++) {
        const double du = fabs(u_new[i] - u_old[i]);
        if (du == 0.0)
            continue;
        if (du > *jump)
            *jump = du;
        const ds_det *d = &m->det[i];
        const double cap = d->C0 * lam[i] * lam[i];
        const double dz = cap * du * d->Rp / (d->Rs + d->Rp);
        if (dz <= st->z_tol)
            continue;
        const double tau = cap * d->Rs * d->Rp / (d->Rs + d->Rp);
        const double t_i = tau * log(dz / st->z_tol);
        if (t_i > *T)
            *T = t_i;
        if (tau < *tau_min)
            *tau_min = tau;
    }
}

/*
 * One control period dt = n_sub h with the input u held, starting from an input u_old. With
 * z_tol > 0 (exponential methods on an RC scene) a charge transient after an input jump is
 * resolved first: graded steps from fine * tau (never coarser than h) until the lag has
 * decayed below z_tol, then steps of at most h to the end of the period. On failure x holds
 * the state at the period's start.
 */
static int fixed_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                        const double *u, double h, int64_t n_sub)
{
    if (st->z_tol > 0.0 && g->m->rc_source) {
        const double dt = h * (double)n_sub;
        double T, tau, jump;
        charge_transient(st, g, x, u_old, u, &T, &tau, &jump);
        if (T > 0.0) {
            const int64_t nx = g->m->n_state;
            memcpy(g->x0, x, (size_t)nx * sizeof(double));
            if (dt < T)
                T = dt;
            /* The local error of a step is about lag(t) (h/tau)^5 and the lag decays like
             * exp(-t/tau), so the step may grow like exp(t / (5 tau)): geometric steps with
             * ratio exp(fine/5) from fine*tau (half the steps of uniform fine*tau steps).
             * fine is calibrated for jumps of jump_ref (the 'step' scenes' v_max); a smaller
             * jump du leaves a lag du/jump_ref as large, so the same local error allows a
             * first step (jump_ref/du)^(1/5) longer: a controller's 1 V change per period
             * took 22 steps per period, now 11, at the same error. */
            double fine = st->fine;
            if (st->jump_ref > 0.0 && jump < st->jump_ref)
                fine *= pow(st->jump_ref / jump, 0.2);
            double h0 = fine * tau < h ? fine * tau : h;
            double gr = exp(h0 / (5.0 * tau));
            int64_t n_fine = (int64_t)ceil(log(1.0 + T * (gr - 1.0) / h0) / log(gr) - 1e-9);
            h0 = T * (gr - 1.0) / (pow(gr, (double)n_fine) - 1.0);
            if (h0 * pow(gr, (double)(n_fine - 1)) > h) {   /* never coarser than h */
                n_fine = (int64_t)ceil(T / h0 - 1e-9);
                h0 = T / (double)n_fine;
                gr = 1.0;
            }
            int status = ds_advance(st, g, x, u, h0, n_fine, gr);
            const double rest = dt - T;
            if (status == DS_OK && rest > 1e-6 * dt) {
                const int64_t n_rest = (int64_t)ceil(rest / h - 1e-9);
                status = ds_advance(st, g, x, u, rest / (double)n_rest, n_rest, 1.0);
            }
            if (status != DS_OK)
                memcpy(x, g->x0, (size_t)nx * sizeof(double));
            return status;
        }
    }
    return ds_advance(st, g, x, u, h, n_sub, 1.0);
}

/*
 * One control period of one group in g->ctl.n steps (plus a charge transient's graded steps).
 * With a local tolerance ctl.tol > 0 the count adapts from period to period (fixed steps inside
 * each period): a period whose largest embedded estimate exceeds the tolerance, or that left
 * the domain, is repeated with more steps (up to n_max), and the next period starts from the
 * count the estimate predicts (estimate ~ n^-exponent), never below n_min nor below half the
 * current count. On failure x holds the state at the period's start.
 */
static int period_core(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                       const double *u)
{
    ds_control *ctl = &g->ctl;
    const double dt = st->dt;
    if (ctl->tol <= 0.0)
        return fixed_period(st, g, x, u_old, u, dt / (double)ctl->n, ctl->n);
    const int64_t nx = g->m->n_state;
    memcpy(g->x_keep, x, (size_t)nx * sizeof(double));
    for (;;) {
        const int64_t n = ctl->n;
        g->est = 0.0;
        int status = fixed_period(st, g, x, u_old, u, dt / (double)n, n);
        if (n < ctl->n_max && (status != DS_OK || g->est > ctl->tol)) {
            const double grow = status != DS_OK
                                ? 4.0 : 1.2 * pow(g->est / ctl->tol, 1.0 / ctl->exponent);
            int64_t next = (int64_t)ceil((double)n * grow);
            if (next < n + 1)
                next = n + 1;
            ctl->n = next < ctl->n_max ? next : ctl->n_max;
            memcpy(x, g->x_keep, (size_t)nx * sizeof(double));
            continue;
        }
        if (status != DS_OK)
            return status;
        const double ratio = pow(g->est / (CTL_SAFETY * ctl->tol), 1.0 / ctl->exponent);
        int64_t next = (int64_t)ceil((double)n * ratio - 1e-9);
        if (next < (n + 1) / 2)
            next = (n + 1) / 2;
        if (next < ctl->n_min)
            next = ctl->n_min;
        ctl->n = next < ctl->n_max ? next : ctl->n_max;
        return DS_OK;
    }
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
        return period_core(st, &st->group[0], x, u_old, u);
    const int64_t n_groups = st->n_groups;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(st->threads) if (st->threads > 1)
#endif
    for (int64_t gi = 0; gi < n_groups; gi++) {
        ds_group *g = &st->group[gi];
        gather(m, g, x, g->x_local);
        g->status = period_core(st, g, g->x_local, u_old + g->c_first, u + g->c_first);
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

/*
 * ds_run for independent groups on several threads without a join per period: each thread
 * runs its groups through RUN_CHUNK periods (states straight into their columns of X, the
 * energies each group books per period into ``booked``), then one thread completes those
 * periods in order: input-jump bookkeeping, energies added in group order, outputs. The
 * arithmetic is that of run_serial, so results are bit-identical for any thread count. One
 * thread runs this way too: a group's scratch stays in cache for its RUN_CHUNK periods instead
 * of every group's being walked once per period (1000 copies: 8 % less time than run_serial).
 */
static int run_chunked(ds_stepper *st, ds_work *ow, double *x, const double *u_held,
                       const double *u_last, const double *U, int64_t n, double *X, double *Y,
                       int64_t *done)
{
    const ds_model *m = st->model;
    const int64_t nx = m->n_state, nu = m->n_cells, ny = ds_n_outputs(m);
    const int64_t n_groups = st->n_groups;
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
        for (int64_t gi = 0; gi < n_groups; gi++) {
            ds_group *g = &st->group[gi];
            for (int64_t j = c0; j < c1 && g->status == DS_OK; j++) {
                const double *u = U + j * nu + g->c_first;
                const double *u_old = (j == 0 ? u_last : U + (j - 1) * nu) + g->c_first;
                if (m->power)
                    g->x_local[g->m->i_power] = g->x_local[g->m->i_power + 1] = 0.0;
                g->status = period_core(st, g, g->x_local, u_old, u);
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
        for (k = c0; k < c1; k++) {   /* complete the chunk's periods in order */
            const double *u = U + k * nu;
            ds_book_input_jump(m, x, u_book, u, ow);
            u_book = u;
            for (int64_t gi = 0; gi < n_groups && status == DS_OK; gi++)
                if (failed_at[gi] == k)
                    status = st->group[gi].status;
            if (status != DS_OK)
                break;
            double *row = X + (k + 1) * nx;
            double w_in = 0.0, w_diss = 0.0;
            if (m->power) {
                w_in = x[m->i_power];
                w_diss = x[m->i_power + 1];
                for (int64_t gi = 0; gi < n_groups; gi++) {
                    const double *b = booked + (gi * RUN_CHUNK + (k - c0)) * 2;
                    w_in += b[0];
                    w_diss += b[1];
                }
            }
            memcpy(x, row, (size_t)nx * sizeof(double));
            if (m->power) {
                x[m->i_power] = w_in;
                x[m->i_power + 1] = w_diss;
            }
            status = ds_outputs(m, x, u, Y + (k + 1) * ny, ow);
            if (status != DS_OK)
                break;
            memcpy(row, x, (size_t)nx * sizeof(double));
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
    if (st->n_groups > 1)
        return run_chunked(st, ow, x, u_held, u_last, U, n, X, Y, done);
    return run_serial(st, ow, x, u_held, u_last, U, n, X, Y, done);
}
