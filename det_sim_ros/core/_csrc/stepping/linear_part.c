/*
 * The dense linear part of one group (linear_part.h): its Jacobian over q, qdot by forward
 * differences of the right-hand side, renewed when the state or the input has moved, and the
 * table's weights per step size, kept in a few slots.
 *
 * Every decision depends only on the states and inputs the group has stepped through, like
 * the step-count controller's: runs from a reset are bit-identical.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "stepping/linear_part.h"
#include "physics/physics.h"
#include "stepping/matrix_phi.h"

/* Forward-difference increment: sqrt(eps) times the state's scale (the error norm's). */
#define FD_RELATIVE 1.4901161193847656e-08

void ds_linear_free(ds_linear *lin)
{
    free(lin->mem);
    free(lin->pair_start);
    memset(lin, 0, sizeof(*lin));
}

void ds_linear_reset(ds_linear *lin)
{
    lin->valid = 0;
    lin->next_slot = 0;
    for (int s = 0; s < DS_LIN_SLOTS; s++)
        lin->slot[s].h = 0.0;
    ds_phi_chains_clear(lin->chain, DS_LIN_CHAINS);
}

/* The table's (row, stage) pairs that carry a term, by row (stage order within a row). */
static int64_t index_pairs(ds_linear *lin, const ds_method *me)
{
    const int64_t s = me->n_stages;
    int64_t n = 0;
    lin->pair_start[0] = 0;
    for (int64_t i = 0; i < s + 1; i++) {
        for (int64_t j = 0; j < s; j++) {
            int used = 0;
            for (int64_t t = me->row_start[i]; t < me->row_start[i + 1]; t++)
                used |= me->term_stage[t] == j;
            if (used)
                lin->pair_stage[n++] = j;
        }
        lin->pair_start[i + 1] = n;
    }
    return n;
}

/* Returns -1 (no memory) or -2 (a stage node c_i that is no argument of the table: its
 * phi_0(c_i h A) would need its own exponential). */
int ds_linear_init(ds_linear *lin, const ds_method *me, const ds_model *m)
{
    memset(lin, 0, sizeof(*lin));
    const int64_t s = me->n_stages, nd = 2 * m->n_q, nn = nd * nd, kp = me->k_max + 1;
    for (int64_t i = 0; i < s + 1; i++)
        if ((i == s || me->c[i] != 0.0) && me->ec_arg[i] < 0)
            return -2;
    lin->nd = nd;
    lin->pair_start = calloc((size_t)(s + 2 + me->n_terms + s * (s + 1)), sizeof(int64_t));
    if (!lin->pair_start)
        return -1;
    lin->pair_stage = lin->pair_start + s + 2;
    lin->n_pairs = index_pairs(lin, me);
    /* the embedded estimate h sum_j e_j N_j + e_s f(x+) of an FSAL pair that differs from the
     * method in the last stage's weight only (e_{s-1} = -e_s) takes that weight's matrix:
     * h b_{s-1}(hA) (e_{s-1} N_{s-1} + e_s N(x+)) / b_{s-1}(0) */
    if (me->n_embedded > 0) {
        double b0 = 0.0;
        for (int64_t t = me->row_start[s]; t < me->row_start[s + 1]; t++)
            if (me->term_stage[t] == s - 1)
                b0 += me->coef0[t];
        for (int64_t j = 0; j < s - 1; j++)
            if (me->embedded[j] != 0.0)
                return -2;
        if (b0 == 0.0 || me->embedded[s - 1] != -me->embedded[s])
            return -2;
        lin->est_pair = lin->pair_start[s + 1] - 1;   /* stage s-1 is the row's last */
        lin->est_scale = 1.0 / b0;
    }
    const int64_t per_slot = (s + 1 + lin->n_pairs) * nn;
    const int64_t n_phis = (me->n_args + 1) * kp * nn;
    const int64_t per_chain = ds_phi_chain_doubles(nd, kp - 1);
    const int64_t total = nn + 2 * nd + m->n_cells + DS_LIN_SLOTS * per_slot + n_phis
                          + ds_matrix_phi_work(nd, kp - 1) + 3 * m->n_state
                          + DS_LIN_CHAINS * per_chain;
    lin->mem = calloc((size_t)total, sizeof(double));
    if (!lin->mem) {
        ds_linear_free(lin);
        return -1;
    }
    lin->A = lin->mem;
    lin->x_lin = lin->A + nn;
    lin->u_lin = lin->x_lin + 2 * nd;
    double *next = lin->u_lin + m->n_cells;
    for (int k = 0; k < DS_LIN_SLOTS; k++) {
        lin->slot[k].E = next;
        lin->slot[k].W = next + (s + 1) * nn;
        next += per_slot;
    }
    lin->phis = next;
    lin->work = lin->phis + n_phis;
    lin->xq = lin->work + ds_matrix_phi_work(nd, kp - 1);
    lin->f0 = lin->xq + m->n_state;
    lin->f1 = lin->f0 + m->n_state;
    for (int k = 0; k < DS_LIN_CHAINS; k++)
        ds_phi_chain_init(&lin->chain[k], nd, lin->f1 + m->n_state + k * per_chain);
    return 0;
}

/* Whether x, u are far enough from where A was taken to take it anew. An input within
 * options.refresh_input (V) of A's keeps it: a controller's small per-period corrections would
 * otherwise take A (and its weights) anew every period, and a stale A only moves part of the
 * linear dynamics into the explicit remainder, whose error the step control sees. */
static int needs_refresh(const ds_stepper *st, const ds_group *g, const double *x,
                         const double *u)
{
    const ds_linear *lin = g->lin;
    if (!lin->valid)
        return 1;
    for (int64_t i = 0; i < g->m->n_cells; i++)
        if (fabs(u[i] - lin->u_lin[i]) > st->options.refresh_input)   /* 0: any change */
            return 1;
    for (int64_t k = 0; k < lin->nd; k++)
        if (fabs(x[k] - lin->x_lin[k]) * g->inv_scale[k] > st->options.refresh)
            return 1;
    return 0;
}

/* Whether the q rows of A are exactly [0 I]: q' = qdot, so f - A x is exactly 0 there. */
static int rates_are_velocities(const double *A, int64_t nd)
{
    const int64_t nq = nd / 2;
    for (int64_t r = 0; r < nq; r++)
        for (int64_t c = 0; c < nd; c++)
            if (A[r * nd + c] != (c == nq + r ? 1.0 : 0.0))
                return 0;
    return 1;
}

/*
 * Take A anew at the period's start (x, u) when needed: forward differences of the
 * right-hand side in the coordinates the stages integrate (quasi-static charge on RC scenes),
 * one rhs per column. The increment is sqrt(eps) times the state's scale (its beam length, or
 * length / dt for a rate), made exact in binary (x + d - x). A needs no more accuracy than
 * that: the method is exact in A, whose error only moves part of the linear dynamics into the
 * explicitly treated remainder. Returns a status.
 */
int ds_linear_update(const ds_stepper *st, ds_group *g, const double *x, const double *u)
{
    ds_linear *lin = g->lin;
    if (!needs_refresh(st, g, x, u))
        return DS_OK;
    const ds_model *m = g->m;
    const int64_t nd = lin->nd, nx = m->n_state;
    double *xq = lin->xq;
    memcpy(xq, x, (size_t)nx * sizeof(double));
    if (g->quasi_static)
        ds_shift_charge(m, xq, u, -1.0, &g->w);
    int status = ds_rhs(m, xq, u, lin->f0, &g->w, g->quasi_static);
    for (int64_t j = 0; j < nd && status == DS_OK; j++) {
        const double keep = xq[j], scale = 1.0 / g->inv_scale[j];
        const double size = fabs(keep) > scale ? fabs(keep) : scale;
        xq[j] = keep + FD_RELATIVE * size;
        const double d = xq[j] - keep;
        status = ds_rhs(m, xq, u, lin->f1, &g->w, g->quasi_static);
        xq[j] = keep;
        for (int64_t i = 0; i < nd; i++)
            lin->A[i * nd + j] = (lin->f1[i] - lin->f0[i]) / d;
    }
    if (status != DS_OK)
        return status;
    lin->q_rates = rates_are_velocities(lin->A, nd);
    memcpy(lin->x_lin, x, (size_t)nd * sizeof(double));
    memcpy(lin->u_lin, u, (size_t)m->n_cells * sizeof(double));
    ds_linear_reset(lin);
    lin->valid = 1;
    lin->refreshes++;
    return DS_OK;
}

/* phi_0..k_max of (args[a] h A) for every table argument a into lin->phis (an argument half
 * another's comes from that one's doubling chain; the block set after the last is spare). */
static void argument_phis(const ds_method *me, ds_linear *lin, double h)
{
    const int64_t nd = lin->nd, nn = nd * nd, kp = me->k_max + 1, nb = kp * nn;
    double *spare = lin->phis + me->n_args * nb;
    for (int64_t a = 0; a < me->n_args; a++) {
        double *out = lin->phis + a * nb;
        const double arg = me->args[a];
        if (arg == 0.0) {   /* phi_k(0) = I / k! */
            memset(out, 0, (size_t)nb * sizeof(double));
            double fact = 1.0;
            for (int64_t k = 0; k < kp; k++) {
                if (k > 0)
                    fact *= (double)k;
                for (int64_t i = 0; i < nd; i++)
                    out[k * nn + i * nd + i] = 1.0 / fact;
            }
            continue;
        }
        int64_t twice = -1;
        for (int64_t b = 0; b < me->n_args; b++)
            if (me->args[b] == 2.0 * arg)
                twice = b;
        if (twice >= 0)
            continue;   /* from its double's chain */
        lin->chain_builds += ds_matrix_phis_chained(lin->A, arg * h, nd, kp - 1, lin->chain,
                                                    DS_LIN_CHAINS, out, spare, lin->work);
        for (int64_t b = 0; b < me->n_args; b++)
            if (2.0 * me->args[b] == arg)
                memcpy(lin->phis + b * nb, spare, (size_t)nb * sizeof(double));
    }
}

/* The weights of step size h into a slot: phi_0(c_i h A) per row, and per (row, stage) pair
 * the sum of its terms' weight * phi_k(c_arg h A) (weight * I for a constant term). */
static void fill_slot(const ds_method *me, ds_linear *lin, ds_lin_slot *slot, double h)
{
    const int64_t s = me->n_stages, nd = lin->nd, nn = nd * nd, kp = me->k_max + 1;
    argument_phis(me, lin, h);
    for (int64_t i = 0; i < s + 1; i++) {
        double *E = slot->E + i * nn;
        const int64_t a = me->ec_arg[i];
        const double ci = i < s ? me->c[i] : 1.0;
        if (ci == 0.0 || a < 0) {   /* c = 0 (init checked the others) */
            memset(E, 0, (size_t)nn * sizeof(double));
            for (int64_t r = 0; r < nd; r++)
                E[r * nd + r] = 1.0;
        } else {
            memcpy(E, lin->phis + a * kp * nn, (size_t)nn * sizeof(double));
        }
    }
    for (int64_t i = 0; i < s + 1; i++) {
        for (int64_t p = lin->pair_start[i]; p < lin->pair_start[i + 1]; p++) {
            double *W = slot->W + p * nn;
            memset(W, 0, (size_t)nn * sizeof(double));
            for (int64_t t = me->row_start[i]; t < me->row_start[i + 1]; t++) {
                if (me->term_stage[t] != lin->pair_stage[p])
                    continue;
                const double w = me->term_weight[t];
                if (me->term_phi[t] < 0) {
                    for (int64_t r = 0; r < nd; r++)
                        W[r * nd + r] += w;
                    continue;
                }
                const double *P = lin->phis + (me->term_arg[t] * kp + me->term_phi[t]) * nn;
                for (int64_t e = 0; e < nn; e++)
                    W[e] += w * P[e];
            }
        }
    }
    slot->h = h;
}

/* The weights of step size h: a kept slot, or the next slot in turn filled anew (never
 * ``keep``, the last step's, whose weights its error estimate still needs). */
const ds_lin_slot *ds_linear_weights(const ds_method *me, ds_linear *lin, double h,
                                     const ds_lin_slot *keep)
{
    for (int k = 0; k < DS_LIN_SLOTS; k++)
        if (lin->slot[k].h == h)
            return &lin->slot[k];
    if (&lin->slot[lin->next_slot] == keep)
        lin->next_slot = (lin->next_slot + 1) % DS_LIN_SLOTS;
    ds_lin_slot *slot = &lin->slot[lin->next_slot];
    lin->next_slot = (lin->next_slot + 1) % DS_LIN_SLOTS;
    fill_slot(me, lin, slot, h);
    lin->fills++;
    return slot;
}
