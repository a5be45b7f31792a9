/*
 * The charge's exact coupling to an amplifier output that follows its command (amplifier.c,
 * VA_FOLLOW, with the current linear): in the quasi-static coordinates the charge lag
 * z = q_p - C v_a Rp/(Rs+Rp) and the output v_a of DET i obey, with C frozen per step as the
 * stiff rates are,
 *
 *   z'   = L_z z + c v_a + N_z      c = C Rp/(Rs+Rp) / tau_a = -1 / (Rs L_z tau_a)
 *   v_a' = L_a v_a + N_a            L_a = -1 / tau_a
 *
 * Left to the explicit stages, c v_a is a forcing that decays on tau_a: a step longer than
 * tau_a misses its integral, so the steps had to stay below tau_a long after the transient
 * had settled. Integrated with the block's exact exponential instead, the stages see only the
 * smooth remainder. The block M = [[L_z, c], [0, L_a]] is triangular: phi_k(p M) has the
 * diagonal phi_k(p L_z), phi_k(p L_a) (the stiff weights, stages.c) and the corner
 * c p (phi_k(p L_z) - phi_k(p L_a)) / (p L_z - p L_a), which this file adds: per DET the
 * coupling c, the corner of each stage row's phi_0 (e) and of each term's phi weight (w).
 */
#include <math.h>

#include "stepping/coupling.h"
#include "physics/amplifier.h"
#include "physics/physics.h"

#define CLOSE 1e-4   /* relative gap below which the divided difference is a derivative */
#define MAX_PHI 16   /* phi_0 .. phi_{MAX_PHI - 1} */

#define MAX_ARGS 8   /* distinct phi arguments of a table */

/* Doubles per DET: c, e_0 .. e_s, w_0 .. w_{n_terms - 1}. */
int64_t ds_coupling_size(const ds_method *me)
{
    return 2 + me->n_stages + me->n_terms;
}

/* Whether the coupling can follow the table (else the stages keep c v_a explicit): every
 * nonzero stage node is one of its phi arguments, and the sizes fit the fixed buffers. */
int ds_coupling_fits(const ds_method *me)
{
    if (!me->exponential || me->n_args > MAX_ARGS || me->k_max + 2 > MAX_PHI)
        return 0;
    for (int64_t i = 0; i < me->n_stages + 1; i++)
        if ((i == me->n_stages || me->c[i] != 0.0) && me->ec_arg[i] < 0)
            return 0;
    return 1;
}

/* The divided differences (phi_k(p) - phi_k(q)) / (p - q), k = 0..n-1, into d: at close p, q
 * the derivative at the midpoint, phi_k'(z) = phi_k(z) - k phi_{k+1}(z) (an error of order
 * (p - q)^2, below round-off there). */
static void divided_phis(double p, double q, double *d, int64_t n)
{
    double fp[MAX_PHI], fq[MAX_PHI];
    if (fabs(p - q) > CLOSE * fmax(fabs(p), fabs(q))) {
        ds_phi_all(p, fp, n);
        ds_phi_all(q, fq, n);
        for (int64_t k = 0; k < n; k++)
            d[k] = (fp[k] - fq[k]) / (p - q);
        return;
    }
    ds_phi_all(0.5 * (p + q), fp, n + 1);
    for (int64_t k = 0; k < n; k++)
        d[k] = fp[k] - (double)k * fp[k + 1];
}

/* The corners of DET i's block (coupling c, rates L[kz], L[kv]) for step size h into cp. */
static void det_corners(const ds_method *me, const double *L, double c, int64_t kz, int64_t kv,
                        double h, double *cp)
{
    const int64_t s = me->n_stages;
    double d[MAX_ARGS * MAX_PHI];
    for (int64_t a = 0; a < me->n_args; a++)
        divided_phis(me->args[a] * h * L[kz], me->args[a] * h * L[kv], d + a * MAX_PHI,
                     me->k_max + 1);
    double *e = cp + 1, *w = e + s + 1;
    for (int64_t i = 0; i < s + 1; i++) {
        const double ci = i < s ? me->c[i] : 1.0;
        e[i] = ci == 0.0 ? 0.0 : c * ci * h * d[me->ec_arg[i] * MAX_PHI];
    }
    for (int64_t t = 0; t < me->n_terms; t++) {
        const int64_t a = me->term_arg[t], k = me->term_phi[t];
        w[t] = k < 0 ? 0.0 : c * me->args[a] * h * me->term_weight[t] * d[a * MAX_PHI + k];
    }
}

void ds_coupling_weights(const ds_method *me, ds_group *g, double h)
{
    const ds_model *m = g->m;
    const int64_t size = ds_coupling_size(me);
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        double *cp = g->cpl + i * size;
        const int64_t kz = m->i_qp + i, kv = m->i_va + i;
        cp[0] = 0.0;
        if (g->w.v_law[i] != VA_FOLLOW || g->w.i_law[i] != AMP_LINEAR || !(g->L[kz] < 0.0))
            continue;
        cp[0] = -d->inv_Rs / (g->L[kz] * d->amp_tau);
        det_corners(me, g->L, cp[0], kz, kv, h, cp);
    }
}

void ds_coupling_row(const ds_method *me, const ds_group *g, int64_t row, const double *x,
                     const double *N, double h, double *X)
{
    const ds_model *m = g->m;
    const int64_t size = ds_coupling_size(me), nx = m->n_state, s = me->n_stages;
    for (int64_t i = 0; i < m->n_cells; i++) {
        const double *cp = g->cpl + i * size;
        if (cp[0] == 0.0)
            continue;
        const double *w = cp + 2 + s;
        const int64_t kv = m->i_va + i;
        double acc = cp[1 + row] * x[kv];
        for (int64_t t = me->row_start[row]; t < me->row_start[row + 1]; t++)
            if (w[t] != 0.0)
                acc += h * w[t] * N[me->term_stage[t] * nx + kv];
        X[m->i_qp + i] += acc;
    }
}

void ds_coupling_remainder(const ds_method *me, const ds_group *g, const double *X, double *N)
{
    const ds_model *m = g->m;
    const int64_t size = ds_coupling_size(me);
    for (int64_t i = 0; i < m->n_cells; i++) {
        const double c = g->cpl[i * size];
        if (c != 0.0)
            N[m->i_qp + i] -= c * X[m->i_va + i];
    }
}
