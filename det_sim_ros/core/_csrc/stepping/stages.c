/*
 * The stages of the one stepping core: n steps of an exponential Runge-Kutta scheme declared as
 * a coefficient table (method.c) on one group, with its embedded error estimate.
 *
 * Every decision depends only on the state and the inputs, so runs are bit-identical run to
 * run. The helpers below are inlined into each specialised copy of advance_core (the sizes nx,
 * s, s0, s1 are constants there): they name its parts, the arithmetic is the core's.
 */
#include <math.h>
#include <string.h>

#include "stepping/stages.h"
#include "physics/physics.h"
#include "stepping/coupling.h"
#include "stepping/linear_part.h"

#define CORE_PART static inline __attribute__((always_inline))

int ds_advance_linear(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
                      int64_t n_steps, double growth);

/* The weights of the stiff states [s0, s1) for a step of size h: each term's weight times
 * phi_k(c_arg h L_k) into coef, and exp(c_i h L_k) (row s: exp(h L_k)) into e_c. */
CORE_PART void stiff_weights(const ds_method *me, const double *L, double h, double *phis,
                             double *coef, double *e_c, const int64_t nx, const int64_t s,
                             const int64_t s0, const int64_t s1)
{
    const int64_t kp = me->k_max + 1;
    for (int64_t k = s0; k < s1; k++) {
        const double z = h * L[k];
        for (int64_t a = 0; a < me->n_args; a++)
            ds_phi_all(me->args[a] * z, phis + a * kp, kp);
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
}

/* Row i of the table from x and the stages N into X: stage i's state, or (row s, the weights b)
 * the new state. States without a stiff rate use the merged L = 0 table. */
CORE_PART void stage_row(const ds_method *me, const double *x, const double *N,
                         const double *coef, const double *e_c, double h, int64_t i, double *X,
                         const int64_t nx, const int64_t s0, const int64_t s1)
{
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
}

/* The last step's error estimate, completed by its first-same-as-last term e_s f(x) (N_0 of
 * the next step), max'ed into g->est: weighted, over the mechanical states only. */
CORE_PART void fsal_estimate(ds_group *g, const double *pend, double e_s, const double *N,
                             double h_prev, int64_t nmech)
{
    for (int64_t k = 0; k < nmech; k++) {
        const double e = fabs(h_prev * (pend[k] + e_s * N[k])) * g->inv_scale[k];
        if (e > g->est)
            g->est = e;
    }
}

/* sum_j e_j N_j over the stages of the step just taken: its estimate but the FSAL term. */
CORE_PART void pending_estimate(const double *emb, const double *N, double *pend, int64_t nmech,
                                const int64_t nx, const int64_t s)
{
    for (int64_t k = 0; k < nmech; k++) {
        double acc = 0.0;
        for (int64_t j = 0; j < s; j++)
            acc += emb[j] * N[j * nx + k];
        pend[k] = acc;
    }
}

/* A stage state with a NaN or inf reads as a slope outside the exact kinematics in the
 * right-hand side (its stretch is NaN): name it for what it is. */
static int stage_status(int status, const double *X, int64_t nx)
{
    for (int64_t k = 0; k < nx && status == DS_BAD_SLOPE; k++)
        if (!isfinite(X[k]))
            return DS_NON_FINITE;
    return status;
}

/* One step of size h from x (stiff weights set): the stages N_i, the new state in g->X.
 * h_prev > 0: the previous step's estimate is completed with N_0. Returns a status. */
CORE_PART int one_step(const ds_method *me, ds_group *g, const double *x, const double *u,
                       double h, double h_prev, const int64_t nx, const int64_t s,
                       const int64_t s0, const int64_t s1)
{
    const ds_model *m = g->m;
    double *N = g->N, *X = g->X;
    /* rows 0..s-1 of the table build the stages, row s (the weights b) the new state */
    for (int64_t i = 0; i < s + 1; i++) {
        stage_row(me, x, N, g->coef, g->e_c, h, i, X, nx, s0, s1);
        if (g->cpl)
            ds_coupling_row(me, g, i, x, N, h, X);
        if (i == s)
            break;
        double *Ni = N + i * nx;
        const int status = ds_rhs(m, X, u, Ni, &g->w, g->quasi_static);
        if (status != DS_OK)
            return stage_status(status, X, nx);
        for (int64_t k = s0; k < s1; k++)
            Ni[k] -= g->L[k] * X[k];
        if (g->cpl)
            ds_coupling_remainder(me, g, X, Ni);
        if (i == 0 && h_prev > 0.0)   /* FSAL: N_0 = f(x) completes the last estimate */
            fsal_estimate(g, g->pend, me->embedded[s], N, h_prev, 2 * m->n_q);
    }
    int status = DS_OK;
    for (int64_t k = 0; k < nx; k++)
        if (!isfinite(X[k]))
            status = DS_NON_FINITE;
    return status;
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
    const int64_t nmech = 2 * m->n_q;
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
        status = ds_stiff_rates(m, x, g->L, &g->w, (int)me->exponential);
        if (status != DS_OK)
            break;
        stiff_weights(me, g->L, h, g->phis, g->coef, g->e_c, nx, s, s0, s1);
        if (g->cpl)
            ds_coupling_weights(me, g, h);
        status = one_step(me, g, x, u, h, h_prev, nx, s, s0, s1);
        if (status != DS_OK)
            break;
        memcpy(x, g->X, (size_t)nx * sizeof(double));
        if (me->n_embedded > 0) {
            pending_estimate(me->embedded, g->N, g->pend, nmech, nx, s);
            h_prev = h;
        }
        h *= growth;
    }
    if (status == DS_OK && h_prev > 0.0) {   /* the last step's FSAL term: one more rhs */
        status = ds_rhs(m, x, u, g->N, &g->w, qs);
        fsal_estimate(g, g->pend, me->embedded[s], g->N, h_prev, nmech);
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

/* The one-term layouts (a cell at the paper's level, alone or as an array's copy, with creep
 * and an RC source, with or without the power monitor, under a four-stage table such as ETDRK4
 * or RK4)
 * get their own copy of the core with the sizes as constants, so the compiler unrolls the
 * per-state and per-stage loops and inlines the copies. The arithmetic and its order are the
 * generic core's (no -ffast-math, no contraction): the results are bit-identical. */
int ds_advance(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
               int64_t n_steps, double growth)
{
    const int64_t nx = g->m->n_state, s = st->method.n_stages, s0 = g->s0, s1 = g->s1;
    if (g->lin)
        return ds_advance_linear(st, g, x, u, h, n_steps, growth);
    if (s == 4 && s0 == 3 && s1 == 4) {
        if (nx == 6)
            return advance_core(st, g, x, u, h, n_steps, growth, 6, 4, 3, 4);
        if (nx == 4)
            return advance_core(st, g, x, u, h, n_steps, growth, 4, 4, 3, 4);
    }
    return advance_core(st, g, x, u, h, n_steps, growth, nx, s, s0, s1);
}

/* Row i of the table with the dense linear part over q, qdot (states [0, nd)): there
 * X = phi_0(c_i h A) x + h sum_j W_ij N_j; the other states as stage_row. Terms that are 0
 * bit for bit are skipped (phi_0(0) = I; N on q where q' = qdot is in A): same sums. */
static void stage_row_linear(const ds_method *me, const ds_linear *lin,
                             const ds_lin_slot *slot, const double *x, const double *N,
                             const double *coef, const double *e_c, double h, int64_t i,
                             double *X, int64_t nx, int64_t s0, int64_t s1)
{
    const int64_t nd = lin->nd, nn = nd * nd, c0 = lin->q_rates ? nd / 2 : 0;
    memcpy(X, x, (size_t)nx * sizeof(double));
    for (int64_t t = me->merged_start[i]; t < me->merged_start[i + 1]; t++) {
        const double *Nj = N + me->merged_stage[t] * nx;
        const double wt = h * me->merged_weight[t];
        for (int64_t k = nd; k < s0; k++)
            X[k] += wt * Nj[k];
        for (int64_t k = s1; k < nx; k++)
            X[k] += wt * Nj[k];
    }
    for (int64_t k = s0; k < s1; k++) {
        double acc = e_c[i * nx + k] * x[k];
        for (int64_t t = me->row_start[i]; t < me->row_start[i + 1]; t++)
            acc += h * coef[t * nx + k] * N[me->term_stage[t] * nx + k];
        X[k] = acc;
    }
    const int identity = i < me->n_stages && me->c[i] == 0.0;   /* phi_0(0 h A) = I */
    if (identity && lin->pair_start[i] == lin->pair_start[i + 1])
        return;   /* X = x there (copied above) */
    const double *E = slot->E + i * nn;
    for (int64_t r = 0; r < nd; r++) {
        double acc = x[r];
        if (!identity) {
            acc = 0.0;
            for (int64_t c = 0; c < nd; c++)
                acc += E[r * nd + c] * x[c];
        }
        for (int64_t p = lin->pair_start[i]; p < lin->pair_start[i + 1]; p++) {
            const double *W = slot->W + p * nn + r * nd, *Nj = N + lin->pair_stage[p] * nx;
            double sum = 0.0;
            for (int64_t c = c0; c < nd; c++)
                sum += W[c] * Nj[c];
            acc += h * sum;
        }
        X[r] = acc;
    }
}

/* N = f(X) - L X on the charge and f(X) - A X on q, qdot (N holds f(X) on entry; on q, where
 * q' = qdot is in A, that is qdot - qdot = 0). */
static void linear_remainder(const ds_group *g, const double *X, double *N, int64_t s0, int64_t s1)
{
    const ds_linear *lin = g->lin;
    const int64_t nd = lin->nd, r0 = lin->q_rates ? nd / 2 : 0;
    for (int64_t k = s0; k < s1; k++)
        N[k] -= g->L[k] * X[k];
    for (int64_t r = 0; r < r0; r++)   /* A's row: 1 at qdot_r, 0 elsewhere */
        N[r] -= X[nd / 2 + r];
    for (int64_t r = r0; r < nd; r++) {
        double acc = 0.0;
        for (int64_t c = 0; c < nd; c++)
            acc += lin->A[r * nd + c] * X[c];
        N[r] -= acc;
    }
}

/* The last step's estimate with the dense linear part: h_prev b_{s-1}(h_prev A) (pend +
 * e_s f(x)) scaled to e_{s-1} at A = 0 (see ds_linear_init), max'ed into g->est. */
static void linear_fsal_estimate(ds_group *g, const ds_lin_slot *prev, double e_s,
                                 const double *N, double h_prev)
{
    const ds_linear *lin = g->lin;
    const int64_t nd = lin->nd, c0 = lin->q_rates ? nd / 2 : 0;
    const double *W = prev->W + lin->est_pair * nd * nd;
    double *v = lin->f1;   /* free between Jacobian updates */
    for (int64_t k = 0; k < nd; k++)
        v[k] = g->pend[k] + e_s * N[k];
    for (int64_t r = 0; r < nd; r++) {
        double acc = 0.0;
        for (int64_t c = c0; c < nd; c++)
            acc += W[r * nd + c] * v[c];
        const double e = fabs(h_prev * lin->est_scale * acc) * g->inv_scale[r];
        if (e > g->est)
            g->est = e;
    }
}

/* one_step with the dense linear part (its weights for h in slot, the last step's in prev). */
static int one_step_linear(const ds_method *me, ds_group *g, const ds_lin_slot *slot,
                           const ds_lin_slot *prev, const double *x, const double *u, double h,
                           double h_prev)
{
    const ds_model *m = g->m;
    const int64_t nx = m->n_state, s = me->n_stages, s0 = g->s0, s1 = g->s1;
    double *N = g->N, *X = g->X;
    for (int64_t i = 0; i < s + 1; i++) {
        stage_row_linear(me, g->lin, slot, x, N, g->coef, g->e_c, h, i, X, nx, s0, s1);
        if (g->cpl)
            ds_coupling_row(me, g, i, x, N, h, X);
        if (i == s)
            break;
        double *Ni = N + i * nx;
        const int status = ds_rhs(m, X, u, Ni, &g->w, g->quasi_static);
        if (status != DS_OK)
            return stage_status(status, X, nx);
        linear_remainder(g, X, Ni, s0, s1);
        if (g->cpl)
            ds_coupling_remainder(me, g, X, Ni);
        if (i == 0 && h_prev > 0.0)
            linear_fsal_estimate(g, prev, me->embedded[s], N, h_prev);
    }
    for (int64_t k = 0; k < nx; k++)
        if (!isfinite(X[k]))
            return DS_NON_FINITE;
    return DS_OK;
}

/* advance_core with the dense linear part over q, qdot (taken by ds_linear_update at the
 * period's start): x' = A x + L x + N(x), A on q, qdot and the stiff diagonal L on the charge
 * integrated exactly, the remainder N by the table's stages. */
int ds_advance_linear(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
                      int64_t n_steps, double growth)
{
    const ds_method *me = &st->method;
    const ds_model *m = g->m;
    const int64_t nx = m->n_state, nmech = 2 * m->n_q, s = me->n_stages;
    for (int64_t k = 0; k < nx; k++)
        if (!isfinite(x[k]))
            return DS_NON_FINITE;
    memcpy(g->x_start, x, (size_t)nx * sizeof(double));
    if (g->quasi_static)
        ds_shift_charge(m, x, u, -1.0, &g->w);
    int status = DS_OK;
    double h_prev = 0.0;
    const ds_lin_slot *prev = NULL;   /* the last step's weights (the ring keeps them) */
    for (int64_t step = 0; step < n_steps && status == DS_OK; step++) {
        status = ds_stiff_rates(m, x, g->L, &g->w, (int)me->exponential);
        if (status != DS_OK)
            break;
        stiff_weights(me, g->L, h, g->phis, g->coef, g->e_c, nx, s, g->s0, g->s1);
        if (g->cpl)
            ds_coupling_weights(me, g, h);
        const ds_lin_slot *slot = ds_linear_weights(me, g->lin, h, prev);
        status = one_step_linear(me, g, slot, prev, x, u, h, h_prev);
        prev = slot;
        if (status != DS_OK)
            break;
        memcpy(x, g->X, (size_t)nx * sizeof(double));
        if (me->n_embedded > 0) {
            pending_estimate(me->embedded, g->N, g->pend, nmech, nx, s);
            h_prev = h;
        }
        h *= growth;
    }
    if (status == DS_OK && h_prev > 0.0) {
        status = ds_rhs(m, x, u, g->N, &g->w, g->quasi_static);
        linear_remainder(g, x, g->N, g->s0, g->s1);
        linear_fsal_estimate(g, prev, me->embedded[s], g->N, h_prev);
    }
    if (status != DS_OK) {
        memcpy(x, g->x_start, (size_t)nx * sizeof(double));
        return status;
    }
    g->steps += (double)n_steps;
    if (g->quasi_static)
        ds_shift_charge(m, x, u, 1.0, &g->w);
    return DS_OK;
}
