/*
 * One control period of one coupled group: the charge transient after an input jump (graded
 * steps until the charge lag has decayed), then fixed steps (stages.c) to the period's end, and
 * the per-period step-count controller.
 *
 * Every decision depends only on the state and the inputs, so runs are bit-identical run to
 * run, and a group's result does not depend on the number of threads.
 */
#include <math.h>
#include <string.h>

#include "stepping/period.h"
#include "physics/physics.h"
#include "stepping/amp_period.h"
#include "stepping/linear_part.h"
#include "stepping/stages.h"

#define CTL_SAFETY 0.5   /* aim the next period's estimate at half the local tolerance */

/*
 * After an input jump, how long the charge transient stays above z_tol (C): *T (0 when no
 * transient matters), the shortest charge time constant *tau_min (s) and the largest input
 * jump *jump (V).
 *
 * A jump du moves the charge the circuit relaxes to by dz = C du Rp/(Rs+Rp); the lag decays
 * like dz exp(-t/tau) with tau = C (Rs || Rp). While it is large it changes the electrostatic
 * force on the time scale tau, which explicit mechanics stages with steps >> tau cannot follow
 * (docs/numerics.md, "Stepping", has what resolving it buys).
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

/* Dyadic levels below h a transient may step at: h 2^-30 is far below any charge time. */
#define DYADIC_LEVELS 30
/* From this many linearized coordinates (n_r 6) a transient climbs back to h by halvings
 * rather than taking one step to the grid of h. A new step size costs a phi chain, ~nd^3, a
 * step ~nd^2: with few coordinates the step to the grid is cheaper, with many the climb (the
 * grid's (1 - 2^-k) h sizes need chains of their own after each Jacobian). The measurements:
 * docs/numerics.md, "Charge transients in dyadic steps". */
#define CLIMB_MIN_ND 12

/*
 * The charge transient under the linearized method. Each new step size costs its weights (a
 * matrix phi, linear_part.c), and the graded sizes h0 gr^i and the remainder's (dt - T) / n
 * are new every period (a controller moves its command every period): here the steps are
 * dyadic, h 2^-k, the largest that starts on its own grid within the graded steps' envelope
 * h0 + t (gr - 1), so they repeat from period to period and are levels of the phi chain of h.
 * Past the transient one step reaches the grid of h (or, with ``climb``, halvings climb
 * back to it), and the period ends in whole steps of h.
 */
static int dyadic_transient(const ds_stepper *st, ds_group *g, double *x, const double *u,
                            double h, int64_t n_sub, double T, double h0, double slope,
                            int climb)
{
    const int64_t per_h = (int64_t)1 << DYADIC_LEVELS, end = n_sub * per_h;
    int64_t t = 0;   /* in units of h 2^-DYADIC_LEVELS */
    while (t < end) {
        const double elapsed = ldexp(h * (double)t, -DYADIC_LEVELS);
        const int past = elapsed >= T;
        if (past && t % per_h == 0)
            return ds_advance(st, g, x, u, h, (end - t) / per_h, 1.0);
        int64_t step;
        if (past && !climb) {
            step = per_h - t % per_h;
        } else {
            const double bound = past ? h : h0 + elapsed * slope;
            int k = 0;
            while (k < DYADIC_LEVELS && (ldexp(h, -k) > bound || t % (per_h >> k) != 0))
                k++;
            step = per_h >> k;
        }
        const int status = ds_advance(st, g, x, u, ldexp(h * (double)step, -DYADIC_LEVELS),
                                      1, 1.0);
        if (status != DS_OK)
            return status;
        t += step;
    }
    return DS_OK;
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
    if (g->m->amp)   /* the amplifier's switches split the steps (amp_period.c) */
        return ds_amp_period(st, g, x, u_old, u, h, n_sub);
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
             * first step (jump_ref/du)^(1/5) longer (a controller's small changes per period
             * take half the steps at the same error: docs/numerics.md, "Stepping"). */
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
            if (g->lin) {
                const int status = dyadic_transient(st, g, x, u, h, n_sub, T, h0, gr - 1.0,
                                                    g->lin->nd >= CLIMB_MIN_ND);
                if (status != DS_OK)
                    memcpy(x, g->x0, (size_t)nx * sizeof(double));
                return status;
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

/* With a dense linear part, step counts are rounded up to 1, 2, 3, 4, 5, 6, 8, 10, 12, 16,
 * 20, 24, 32, ... (at most 4/3 apart): the step sizes then repeat from period to period, and
 * so do their weights, which cost ~50 small matrix products each (linear_part.c). */
static int64_t count_ladder(int64_t n)
{
    if (n <= 6)
        return n;
    int64_t base = 4;
    while (base * 2 < n)
        base *= 2;
    /* n in (base, 2 base]: the rungs 1.25, 1.5, 2 times base */
    if (n <= base + base / 4)
        return base + base / 4;
    if (n <= base + base / 2)
        return base + base / 2;
    return 2 * base;
}

/*
 * One control period of one group in g->ctl.n steps (plus a charge transient's graded steps).
 * With a local tolerance ctl.tol > 0 the count adapts from period to period (fixed steps inside
 * each period): a period whose largest embedded estimate exceeds the tolerance, or that left
 * the domain, is repeated with more steps (up to n_max), and the next period starts from the
 * count the estimate predicts (estimate ~ n^-exponent), never below n_min nor below half the
 * current count. On failure x holds the state at the period's start.
 */
int ds_stages_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                     const double *u)
{
    ds_control *ctl = &g->ctl;
    const double dt = st->dt;
    if (g->lin) {   /* the dense linear part, taken anew if the state has moved */
        const int status = ds_linear_update(st, g, x, u);
        if (status != DS_OK)
            return status;
    }
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
            if (g->lin)
                next = count_ladder(next);
            ctl->n = next < ctl->n_max ? next : ctl->n_max;
            memcpy(x, g->x_keep, (size_t)nx * sizeof(double));
            g->repeated += 1.0;
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
        if (g->lin)
            next = count_ladder(next);
        ctl->n = next < ctl->n_max ? next : ctl->n_max;
        return DS_OK;
    }
}
