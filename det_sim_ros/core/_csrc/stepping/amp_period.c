/*
 * An amplified control period (see physics/amplifier.h for the laws): the steps end where a
 * law switches. A slew ends at a time known in advance (v_a does not depend on the load); the
 * current limit's switches depend on the state and are located: a step that ends with a DET's
 * current past the switch is retried shorter (regula falsi on the step size) until it ends
 * within DS_AMP_LIMIT_MARGIN of the switch, on its far side, so at a switch the current moves
 * by at most 2 DS_AMP_LIMIT_MARGIN I. (A step that leaves the limit and comes back within
 * itself, e.g. a DET discharged through 0 V, is caught by the signed test.) A period whose
 * currents cannot come near a limit (may_reach_limit) steps as if there were none. Each law's
 * linear part goes to the exponential stages, with the charge's coupling to a following v_a
 * exact (coupling.c); so no stiff term is left to the explicit stages.
 */
#include <math.h>
#include <string.h>

#include "stepping/amp_period.h"
#include "physics/amplifier.h"
#include "physics/physics.h"
#include "stepping/linear_part.h"
#include "stepping/stages.h"

#define SQRT_HALF 0.70710678118654752440
#define MAX_LOCATE 60       /* regula falsi iterations to locate a current-limit switch */
#define REACH_SHARE 0.5     /* a period whose currents stay below this share of the limit
                               steps without watching for the limit */

/* How far past its switch the current law of any DET ended (>= 0: a switch was passed). */
static double passed_switch(const ds_model *m, const double *x, const double *u, ds_work *w)
{
    double worst = -INFINITY;
    ds_stretches(m, x, w, w->Us4);   /* w->y */
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        if (!(d->amp_imax > 0.0))
            continue;
        const double past = ds_amp_past_switch(m, i, x, u, w);
        if (past > worst)
            worst = past;
    }
    return worst;
}

/* The time (from now) at which the first slewing output reaches its target band. */
static double slew_end(const ds_model *m, const double *x, const double *u, const ds_work *w)
{
    double t = INFINITY;
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        if (w->v_law[i] != VA_SLEW_UP && w->v_law[i] != VA_SLEW_DOWN)
            continue;
        const double ti = (fabs(u[i] - x[m->i_va + i]) - d->amp_slew * d->amp_tau)
                          / d->amp_slew;
        if (ti < t)
            t = ti;
    }
    return t;
}

/* The slewing outputs whose ramp ends within this step of length h from x_start: exactly at
 * their band's edge (the ramp is exact but for rounding); the charge follows a new slope. */
static void finish_slews(const ds_model *m, const ds_work *w, ds_amp_transient *tr, double *x,
                         const double *x_start, const double *u, double h, double t_now)
{
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        if (w->v_law[i] != VA_SLEW_UP && w->v_law[i] != VA_SLEW_DOWN)
            continue;
        const double band = d->amp_slew * d->amp_tau;
        const double ti = (fabs(u[i] - x_start[m->i_va + i]) - band) / d->amp_slew;
        if (ti > h * (1.0 + 1e-12))
            continue;
        x[m->i_va + i] = w->v_law[i] == VA_SLEW_UP ? u[i] - band : u[i] + band;
        if (d->amp_tau == 0.0) {   /* held from here: the ramp's slope stops */
            tr[i].charge_t0 = t_now;
            tr[i].charge_dv = d->amp_slew * tr[i].charge_tau;
        } else {                   /* following from here: v_a bends on tau_a */
            tr[i].output_t0 = t_now;
            tr[i].output_dv = band;
        }
    }
}

/*
 * The transients a control period starts with (see period.c, charge_transient): a command
 * jump du moves the charge's target at once (no output lag) or through v_a (a bandwidth: v_a
 * itself relaxes on tau_a, and the charge lags by about du tau/(tau + tau_a); a slew: the
 * charge lags the ramp by S tau). w->y from ds_stretches.
 */
static void start_transients(const ds_model *m, ds_amp_transient *tr, const double *x,
                             const double *u_old, const double *u, const ds_work *w)
{
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        ds_amp_transient *t = &tr[i];
        double cap;
        ds_amp_det_voltage(m, i, x, w, &cap);
        t->charge_tau = cap * d->Rs * d->share;   /* C (Rs || Rp) */
        t->charge_t0 = t->output_t0 = 0.0;
        t->charge_dv = t->output_dv = 0.0;
        if (u[i] == u_old[i])
            continue;
        if (!m->amp_state || !ds_amp_has_output_state(d)) {
            t->charge_dv = fabs(u[i] - u_old[i]);
            continue;
        }
        const double gap = fabs(u[i] - x[m->i_va + i]);
        if (w->v_law[i] == VA_FOLLOW) {
            t->output_dv = gap;
            t->charge_dv = gap * t->charge_tau / (t->charge_tau + d->amp_tau);
        } else if (w->v_law[i] != VA_HOLD) {
            t->charge_dv = fmin(gap, d->amp_slew * t->charge_tau);
        }
    }
}

/* The largest step a transient of size dv (V) on the time scale tau allows, ``since`` its start
 * (the graded steps of period.c: fine tau (jump_ref/dv)^(1/5), growing like exp(t/(5 tau)),
 * until the charge lag cap_share dv exp(-t/tau) is below z_tol). */
static double graded(const ds_stepper *st, double tau, double dv, double cap_share,
                     double since)
{
    if (!(tau > 0.0) || !(dv * cap_share > st->z_tol))
        return INFINITY;
    if (since >= tau * log(dv * cap_share / st->z_tol))
        return INFINITY;
    double fine = st->fine;
    if (st->jump_ref > 0.0 && dv < st->jump_ref)
        fine *= pow(st->jump_ref / dv, 0.2);
    return fine * tau * exp(since / (5.0 * tau));
}

/* The largest step the transients still under way at time t of the period allow. */
static double transient_bound(const ds_stepper *st, const ds_group *g, double t)
{
    const ds_model *m = g->m;
    double bound = INFINITY;
    if (st->z_tol <= 0.0)
        return bound;
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        const ds_amp_transient *tr = &g->transient[i];
        const double cap_share = tr->charge_tau * d->inv_Rs;
        if (g->w.i_law[i] == AMP_LINEAR)
            bound = fmin(bound, graded(st, tr->charge_tau, tr->charge_dv, cap_share,
                                       t - tr->charge_t0));
        if (g->w.v_law[i] == VA_FOLLOW)
            bound = fmin(bound, graded(st, d->amp_tau, tr->output_dv, cap_share,
                                       t - tr->output_t0));
    }
    return bound;
}

/* A graded step under the linearized method: the largest h 2^(-j/2) within ``bound``, so
 * that the graded steps of a transient repeat a few sizes and share their weights (each new
 * size costs a matrix phi, linear_part.c) for at most a factor sqrt(2) of their length. */
static double graded_rung(double h, double bound)
{
    const int j = (int)ceil(2.0 * log2(h / bound) - 1e-9);
    return j % 2 ? ldexp(h * SQRT_HALF, -(j - 1) / 2) : ldexp(h, -j / 2);
}

/* Retry the step just taken from x_start (ending past a current-limit switch) shorter until it
 * ends at most DS_AMP_LIMIT_MARGIN past the switch (Illinois regula falsi on the step size); *h
 * receives its length. A DET that left its limit starts a charge transient (a lag of Rs I). */
static int locate_switch(const ds_stepper *st, ds_group *g, double *x, const double *x_start,
                         const double *u, double *h, double t)
{
    ds_model *m = g->m;
    const size_t bytes = (size_t)m->n_state * sizeof(double);
    double hi = *h, past_hi = passed_switch(m, x, u, &g->w);
    if (past_hi < 0.0)
        return DS_OK;
    double lo = 0.0, f_lo = fmin(passed_switch(m, x_start, u, &g->w), 0.0), f_hi = past_hi;
    int at_hi = 1, side = 0, status = DS_OK;
    for (int it = 0; it < MAX_LOCATE && past_hi > DS_AMP_LIMIT_MARGIN && hi - lo > 1e-15 * hi;
         it++) {
        double h_try = lo - f_lo * (hi - lo) / (f_hi - f_lo);
        if (!(h_try > lo && h_try < hi))
            h_try = 0.5 * (lo + hi);
        memcpy(x, x_start, bytes);
        status = ds_advance(st, g, x, u, h_try, 1, 1.0);
        if (status != DS_OK)
            return status;
        const double past = passed_switch(m, x, u, &g->w);
        if (past >= 0.0) {
            hi = h_try;
            f_hi = past_hi = past;
            if (side == 1)
                f_lo *= 0.5;
            side = 1;
        } else {
            lo = h_try;
            f_lo = past;
            if (side == -1)
                f_hi *= 0.5;
            side = -1;
        }
        at_hi = past >= 0.0;
    }
    if (!at_hi) {
        memcpy(x, x_start, bytes);
        status = ds_advance(st, g, x, u, hi, 1, 1.0);
    }
    *h = hi;
    ds_stretches(m, x, &g->w, g->w.Us4);   /* w->y */
    for (int64_t i = 0; i < m->n_cells && status == DS_OK; i++) {
        const ds_det *d = &m->det[i];
        if (g->w.i_law[i] != AMP_LINEAR && ds_amp_past_switch(m, i, x, u, &g->w) >= 0.0) {
            g->transient[i].charge_t0 = t + hi;
            g->transient[i].charge_dv = d->Rs * d->amp_imax;
        }
    }
    return status;
}

/* Whether DET i's current could reach its limit: a limit law now, or a linear current that
 * the source's range [lo, hi] over the period (v_a moves monotonically to u) could take past
 * REACH_SHARE of the limit. With C held, v_p stays between its start and share times the
 * source, so |v_src - v_p| stays within the gaps below; the mechanics moves v_p on its own,
 * slower time scale, which the margin and the period's end check (ends_near_limit) cover. */
static int may_reach_limit(const ds_model *m, int64_t i, const double *x, const double *u,
                           const ds_work *w)
{
    const ds_det *d = &m->det[i];
    if (!(d->amp_imax > 0.0))
        return 0;
    if (w->i_law[i] != AMP_LINEAR)
        return 1;
    double cap;
    const double vp = ds_amp_det_voltage(m, i, x, w, &cap);
    const double v_src = ds_amp_source_voltage(m, d, i, x, u);
    const double lo = fmin(v_src, u[i]), hi = fmax(v_src, u[i]);
    const double vp_lo = fmin(vp, d->share * lo), vp_hi = fmax(vp, d->share * hi);
    const double gap = fmax(fabs(hi - vp_lo), fabs(vp_hi - lo));
    return !(gap * d->inv_Rs < REACH_SHARE * d->amp_imax);
}

/* Whether any DET's current may reach its limit in the period from x (w->y from ds_stretches). */
static int limit_within_reach(const ds_model *m, const double *x, const double *u,
                              const ds_work *w)
{
    for (int64_t i = 0; i < m->n_cells; i++)
        if (may_reach_limit(m, i, x, u, w))
            return 1;
    return 0;
}

/* Whether any DET ended the period with its current beyond REACH_SHARE of its limit. */
static int ends_near_limit(const ds_model *m, const double *x, const double *u, ds_work *w)
{
    ds_stretches(m, x, w, w->Us4);   /* w->y */
    for (int64_t i = 0; i < m->n_cells; i++)
        if (m->det[i].amp_imax > 0.0 && !(fabs(ds_amp_linear_share(m, i, x, u, w)) < REACH_SHARE))
            return 1;
    return 0;
}

/* The steps of one period from x (its laws and transients set): with ``limited`` each step alone
 * (a current limit's switch is located after each), else the rest of the period in one call
 * as soon as no law can switch before its end. */
static int period_steps(const ds_stepper *st, ds_group *g, double *x, const double *u,
                        double h, int64_t n_sub, int limited)
{
    ds_model *m = g->m;
    const size_t bytes = (size_t)m->n_state * sizeof(double);
    const double dt = h * (double)n_sub;
    double *x_start = g->w.dx;   /* free while stepping (the rate buffer of ds_outputs) */
    double t = 0.0;
    int status = DS_OK;
    while (status == DS_OK && dt - t > 1e-9 * h) {
        const double rest = dt - t, n_rest = ceil(rest / h - 1e-9);
        /* h itself while the steps so far were whole steps: equal sizes share their weights */
        double hs = fabs(n_rest * h - rest) <= 1e-9 * h ? h : rest / n_rest;
        const double bound = transient_bound(st, g, t), t_slew = slew_end(m, x, u, &g->w);
        if (!limited && bound >= hs && t_slew >= rest * (1.0 + 1e-12)) {
            /* no law can switch before the period's end and the graded bounds only grow */
            return ds_advance(st, g, x, u, hs, (int64_t)n_rest, 1.0);
        }
        if (bound < hs)
            hs = g->lin ? graded_rung(h, bound) : bound;
        hs = fmin(hs, t_slew);
        memcpy(x_start, x, bytes);
        status = ds_advance(st, g, x, u, hs, 1, 1.0);
        if (status == DS_OK && limited)
            status = locate_switch(st, g, x, x_start, u, &hs, t);
        if (status == DS_OK && m->amp_state)
            finish_slews(m, &g->w, g->transient, x, x_start, u, hs, t + hs);
        t += hs;
        ds_stretches(m, x, &g->w, g->w.Us4);   /* w->y */
        ds_amp_laws(m, x, u, &g->w);
    }
    return status;
}

/* One control period: a period in which no current can reach its limit steps as without
 * one (whole calls between the other laws' switches); one that ends near a limit after all
 * is taken again step by step. On failure x holds the state at the period's start. */
int ds_amp_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                  const double *u, double h, int64_t n_sub)
{
    ds_model *m = g->m;
    const size_t bytes = (size_t)m->n_state * sizeof(double);
    memcpy(g->x0, x, bytes);
    ds_stretches(m, x, &g->w, g->w.Us4);   /* w->y */
    ds_amp_laws(m, x, u, &g->w);
    start_transients(m, g->transient, x, u_old, u, &g->w);
    const int limited = limit_within_reach(m, x, u, &g->w);
    g->watched += limited;
    int status = period_steps(st, g, x, u, h, n_sub, limited);
    if (status == DS_OK && !limited && ends_near_limit(m, x, u, &g->w)) {
        g->watched += 1.0;
        memcpy(x, g->x0, bytes);
        ds_stretches(m, x, &g->w, g->w.Us4);   /* w->y */
        ds_amp_laws(m, x, u, &g->w);
        start_transients(m, g->transient, x, u_old, u, &g->w);
        status = period_steps(st, g, x, u, h, n_sub, 1);
    }
    if (status != DS_OK)
        memcpy(x, g->x0, bytes);
    return status;
}
