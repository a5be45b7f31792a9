/*
 * Exponential Runge-Kutta methods as coefficient tables (det_sim_ros/sim/integrators.py): the
 * functions phi_k their weights are made of, and a table decoded into what the stages
 * (stages.c) read per step.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "stepping/method.h"

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
void ds_phi_all(double z, double *out, int64_t n)
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

/* The table's arrays for s stages and nt terms, one allocation per type (zeroed). */
static int method_alloc(ds_method *me, int64_t s, int64_t nt)
{
    memset(me, 0, sizeof(*me));
    me->n_stages = s;
    me->n_terms = nt;
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
    return 0;
}

/* Each term's stage, phi index and weight, and its argument among the distinct c_arg. */
static void decode_terms(ds_method *me, const double *terms)
{
    int64_t n_args = 0, k_max = 0;
    for (int64_t t = 0; t < me->n_terms; t++) {
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
}

/* Where the stages find their terms: the terms with a phi weight, each stage row's terms, and
 * the table argument whose phi_0 is exp(c_i z). */
static void index_terms(ds_method *me, const double *c, const double *terms)
{
    const int64_t s = me->n_stages, nt = me->n_terms, n_args = me->n_args, k_max = me->k_max;
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
}

/* The table at L = 0: each term's weight (phi_k(0) = 1/k!), then terms of equal (row, stage)
 * merged and zeros dropped: what the states without a stiff rate use (Krogstad's 16 terms are
 * classical RK4's 7 there). */
static int merge_constant_table(ds_method *me, const double *terms)
{
    const int64_t s = me->n_stages, nt = me->n_terms, k_max = me->k_max;
    double phis0[64];
    ds_phi_all(0.0, phis0, k_max + 1 < 64 ? k_max + 1 : 64);
    for (int64_t t = 0; t < nt; t++)
        me->coef0[t] = me->term_weight[t] * (me->term_phi[t] < 0 ? 1.0 : phis0[me->term_phi[t]]);
    double *w0 = calloc((size_t)((s + 1) * s), sizeof(double));
    if (!w0)
        return -1;
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
    return 0;
}

/*
 * Decode a table: ``terms`` rows (stage row i, or n_stages for b; stage j; phi index k, -1 for
 * a constant weight; c_arg; weight), sorted by row. ``embedded``: e_0..e_s of the error
 * estimate h sum_j e_j N_j (e_s multiplies f(x_new)), or none (n_embedded = 0).
 */
int ds_method_init(ds_method *me, const double *c, int64_t s, const double *terms, int64_t nt,
                   const double *embedded, int64_t n_embedded)
{
    if (method_alloc(me, s, nt) < 0)
        return -1;
    memcpy(me->c, c, (size_t)s * sizeof(double));
    decode_terms(me, terms);
    index_terms(me, c, terms);
    if (merge_constant_table(me, terms) < 0) {
        ds_method_free(me);
        return -1;
    }
    /* the error estimate needs stage 0 at the step's start (c_0 = 0) for its FSAL term */
    me->n_embedded = (n_embedded == s + 1 && c[0] == 0.0) ? n_embedded : 0;
    memcpy(me->embedded, embedded, (size_t)me->n_embedded * sizeof(double));
    return 0;
}
