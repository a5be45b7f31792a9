/*
 * The variable-order BDF stepper (bdf.h): the numerical differentiation formulas of orders 1-5
 * with a quasi-constant step (Shampine & Reichelt, SIAM J. Sci. Comput. 18, 1997; the scheme
 * of scipy's integrate/_ivp/bdf.py, split by job as it is), the history as backward
 * differences D, a simplified Newton iteration with the Jacobian kept while it converges. Each
 * period's steps fit it evenly, so the state at its end is the method's own and an input that
 * changes there starts the next step from it. det_sim_ros/physics/reference_bdf.py documents
 * the choices.
 *
 * Every decision depends only on the states and inputs stepped through: runs from a reset are
 * bit-identical, and a group's result does not depend on the number of threads.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "stepping/bdf.h"
#include "physics/physics.h"

#define NEWTON_MAXITER 6   /* corrections before Newton gives up (reference_bdf.py: why) */
#define NEWTON_TOL 0.1     /* Newton's remaining error, in units of the local tolerance */
#define MIN_FACTOR 0.2
#define MAX_FACTOR 10.0
#define FD_RELATIVE 1.4901161193847656e-08   /* sqrt(eps) */
#define MIN_STEP_FRACTION 1e-10              /* of the period: below it the step fails */
#define MAX_ATTEMPTS 100000                  /* steps tried per period before it fails */
#define N_ROWS (DS_BDF_MAX_ORDER + 3)
#define LU_KEEP 0.3   /* the LU serves while c is within this fraction of its own */
#define FIT_ROUND_OFF 1e-9   /* a fit to the period moving the step less: round-off, no change */

/* What one attempted step came to (try_step). */
enum { STEP_ACCEPTED, STEP_NEWTON_FAILED, STEP_ERROR_FAILED };

static const double KAPPA[DS_BDF_MAX_ORDER + 1] = {0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415,
                                                   0.0};

/* gamma_k = sum_{j=1..k} 1/j, alpha_k = (1 - kappa_k) gamma_k and the error constants
 * kappa_k gamma_k + 1/(k+1), summed as numpy's cumsum does. */
static void tables(ds_bdf *bdf)
{
    double gamma = 0.0;
    for (int k = 0; k <= DS_BDF_MAX_ORDER; k++) {
        if (k > 0)
            gamma += 1.0 / (double)k;
        bdf->gamma[k] = gamma;
        bdf->alpha[k] = (1.0 - KAPPA[k]) * gamma;
        bdf->error_const[k] = KAPPA[k] * gamma + 1.0 / (double)(k + 1);
    }
}

int ds_bdf_init(ds_bdf *bdf, int64_t n, int64_t n_core, const double *weights, double tol)
{
    memset(bdf, 0, sizeof(*bdf));
    bdf->n = n;
    bdf->n_core = n_core;
    bdf->tol = tol;
    const int64_t total = N_ROWS * n + 4 * n * n + 9 * n;
    double *mem = calloc((size_t)total, sizeof(double));
    bdf->piv = calloc((size_t)n, sizeof(int64_t));
    if (!mem || !bdf->piv) {
        free(mem);
        free(bdf->piv);
        bdf->piv = NULL;
        return -1;
    }
    bdf->mem = mem;
    bdf->D = mem;
    bdf->J = bdf->D + N_ROWS * n;
    bdf->LU = bdf->J + n * n;
    bdf->LT = bdf->LU + n * n;
    bdf->w = bdf->LT + n * n;
    bdf->y_predict = bdf->w + n;
    bdf->psi = bdf->y_predict + n;
    bdf->y = bdf->psi + n;
    bdf->d = bdf->y + n;
    bdf->dy = bdf->d + n;
    bdf->f = bdf->dy + n;
    bdf->f0 = bdf->f + n;
    bdf->xp = bdf->f0 + n;
    memcpy(bdf->w, weights, (size_t)n * sizeof(double));
    tables(bdf);
    return 0;
}

void ds_bdf_free(ds_bdf *bdf)
{
    free(bdf->mem);
    free(bdf->piv);
    memset(bdf, 0, sizeof(*bdf));
}

void ds_bdf_reset(ds_bdf *bdf)
{
    bdf->has_history = 0;
}

/* The weighted max norm of scale * v over the tolerance; NaN if any component is NaN (numpy's
 * max): a NaN must fail every test it enters, never be skipped by a comparison. */
static double norm(const ds_bdf *bdf, const double *v, double scale)
{
    double largest = 0.0;
    for (int64_t i = 0; i < bdf->n_core; i++) {
        const double e = fabs(scale * v[i]) * bdf->w[i];
        if (e > largest || e != e)
            largest = e;
        if (largest != largest)
            return largest;
    }
    return largest / bdf->tol;
}

/* The differences D[:order + 1] of step h_abs rescaled to h_abs * factor = h_new:
 * D = RU^T D with RU = R(factor) R(1) (scipy's change_D). */
static void rescale(ds_bdf *bdf, double factor, double h_new)
{
    const int m = bdf->order + 1;
    double R[DS_BDF_MAX_ORDER + 1][DS_BDF_MAX_ORDER + 1], U[DS_BDF_MAX_ORDER + 1][DS_BDF_MAX_ORDER + 1];
    double RU[DS_BDF_MAX_ORDER + 1][DS_BDF_MAX_ORDER + 1];
    for (int pass = 0; pass < 2; pass++) {
        double (*M)[DS_BDF_MAX_ORDER + 1] = pass ? U : R;
        const double f = pass ? 1.0 : factor;
        for (int j = 0; j < m; j++)
            M[0][j] = 1.0;
        for (int i = 1; i < m; i++) {   /* cumulative products down the rows */
            M[i][0] = 0.0;
            for (int j = 1; j < m; j++)
                M[i][j] = M[i - 1][j] * (((double)(i - 1) - f * (double)j) / (double)i);
        }
    }
    for (int i = 0; i < m; i++)
        for (int j = 0; j < m; j++) {
            double s = 0.0;
            for (int k = 0; k < m; k++)
                s += R[i][k] * U[k][j];
            RU[i][j] = s;
        }
    const int64_t n = bdf->n;
    double *column = bdf->xp;   /* free outside the Jacobian */
    for (int64_t c = 0; c < n; c++) {
        for (int j = 0; j < m; j++) {
            double s = 0.0;
            for (int i = 0; i < m; i++)
                s += RU[i][j] * bdf->D[i * n + c];
            column[j] = s;
        }
        for (int j = 0; j < m; j++)
            bdf->D[j * n + c] = column[j];
    }
    bdf->h_abs = h_new;
}

/* A new step size h_new = h_abs * factor: the history rescaled to it. */
static void change_step(ds_bdf *bdf, double factor, double h_new)
{
    rescale(bdf, factor, h_new);
    bdf->n_equal_steps = 0;
}

/* LU with partial pivoting of I - c J (the core block) into LU. Returns 0, or -1 when
 * singular. */
static int factorize(ds_bdf *bdf, double c)
{
    const int64_t n = bdf->n_core;
    double *a = bdf->LU;
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++)
            a[i * n + j] = (i == j ? 1.0 : 0.0) - c * bdf->J[i * n + j];
    for (int64_t k = 0; k < n; k++) {
        int64_t p = k;
        for (int64_t i = k + 1; i < n; i++)
            if (fabs(a[i * n + k]) > fabs(a[p * n + k]))
                p = i;
        bdf->piv[k] = p;
        if (a[p * n + k] == 0.0)
            return -1;
        if (p != k)
            for (int64_t j = 0; j < n; j++) {
                const double t = a[k * n + j];
                a[k * n + j] = a[p * n + j];
                a[p * n + j] = t;
            }
        const double inv = 1.0 / a[k * n + k];
        for (int64_t i = k + 1; i < n; i++) {
            const double l = a[i * n + k] * inv;
            a[i * n + k] = l;
            for (int64_t j = k + 1; j < n; j++)
                a[i * n + j] -= l * a[k * n + j];
        }
    }
    for (int64_t i = 0; i < n; i++)   /* the transpose the solves read by columns */
        for (int64_t j = 0; j < n; j++)
            bdf->LT[j * n + i] = a[i * n + j];
    bdf->factorizations += 1;
    bdf->lu_c = c;
    return 0;
}

/* v = (I - c J)^-1 v over the core states with the factors, column by column from their
 * transpose LT: each column's update is independent across rows (no chain of dependent sums
 * per row). */
static void solve(const ds_bdf *bdf, double *v)
{
    const int64_t n = bdf->n_core;
    const double *lt = bdf->LT;
    for (int64_t k = 0; k < n; k++) {
        const int64_t p = bdf->piv[k];
        if (p != k) {
            const double t = v[k];
            v[k] = v[p];
            v[p] = t;
        }
    }
    for (int64_t j = 0; j < n; j++) {   /* L, unit diagonal */
        const double t = v[j];
        const double *col = lt + j * n;
        for (int64_t i = j + 1; i < n; i++)
            v[i] -= col[i] * t;
    }
    for (int64_t j = n - 1; j >= 0; j--) {   /* U */
        const double *col = lt + j * n;
        v[j] /= col[j];
        const double t = v[j];
        for (int64_t i = 0; i < j; i++)
            v[i] -= col[i] * t;
    }
}

/* J = df/dx at x by forward differences (increments sqrt(eps) max(|x_j|, 1 / w_j)): the
 * columns of the n_core states, their rows as an n_core square (the iteration matrix's) and
 * the bookkeeping states' rows after it. A J with a NaN or inf is not kept: DS_NON_FINITE. */
static int jacobian(ds_bdf *bdf, ds_group *group, const double *x, const double *u)
{
    const int64_t n = bdf->n_core;
    int status = ds_rhs(group->m, x, u, bdf->f0, &group->w, 0);
    memcpy(bdf->xp, x, (size_t)bdf->n * sizeof(double));
    for (int64_t j = 0; j < n && status == DS_OK; j++) {
        const double scale = bdf->w[j] > 0.0 ? 1.0 / bdf->w[j] : 1.0;
        const double size = fabs(x[j]) > scale ? fabs(x[j]) : scale;
        bdf->xp[j] = x[j] + FD_RELATIVE * size;
        const double increment = bdf->xp[j] - x[j];
        status = ds_rhs(group->m, bdf->xp, u, bdf->f, &group->w, 0);
        bdf->xp[j] = x[j];
        for (int64_t i = 0; i < bdf->n; i++)   /* the bookkeeping rows after the core block */
            bdf->J[i < n ? i * n + j : n * n + (i - n) * n + j]
                = (bdf->f[i] - bdf->f0[i]) / increment;
    }
    bdf->jacobians += 1;
    if (bdf->nan_after > 0 && --bdf->nan_after == 0) {   /* a planted fault (tests only) */
        bdf->J[0] = NAN;
        bdf->nan_after = bdf->nan_lasting;
    }
    bdf->lu_c = 0.0;   /* the LU is of the old J */
    int finite = 1;
    for (int64_t k = 0; k < bdf->n * n; k++)
        finite &= isfinite(bdf->J[k]);
    bdf->has_jac = finite;
    bdf->jac_is_current = 1;
    if (status == DS_OK && !finite)
        status = DS_NON_FINITE;
    return status;
}

/* The simplified Newton iteration of one step: y (from y_predict), d = y - y_predict. Returns 1
 * when it converged, with *n_iter the iterations it took. The bookkeeping states (past n_core)
 * no rate reads make I - c J block lower triangular: the core's block is solved alone (the
 * same arithmetic with or without them) and their rows by substitution after it. */
static int newton(ds_bdf *bdf, ds_group *group, const double *u, double c, int *n_iter)
{
    const int64_t n = bdf->n, nc = bdf->n_core;
    memcpy(bdf->y, bdf->y_predict, (size_t)n * sizeof(double));
    memset(bdf->d, 0, (size_t)n * sizeof(double));
    double dy_norm_old = -1.0;
    for (int k = 0; k < NEWTON_MAXITER; k++) {
        if (ds_rhs(group->m, bdf->y, u, bdf->f, &group->w, 0) != DS_OK)
            break;
        int finite = 1;
        for (int64_t i = 0; i < n; i++)
            finite &= isfinite(bdf->f[i]);
        if (!finite) {
            bdf->failed_non_finite = 1;
            break;
        }
        for (int64_t i = 0; i < n; i++)
            bdf->dy[i] = c * bdf->f[i] - bdf->psi[i] - bdf->d[i];
        solve(bdf, bdf->dy);
        for (int64_t i = nc; i < n; i++) {   /* the bookkeeping rows: dy_b + lu_c J_bc dy_c */
            const double *row = bdf->J + nc * nc + (i - nc) * nc;
            double s = 0.0;
            for (int64_t j = 0; j < nc; j++)
                s += row[j] * bdf->dy[j];
            bdf->dy[i] += bdf->lu_c * s;
        }
        const double dy_norm = norm(bdf, bdf->dy, 1.0);
        if (!(dy_norm < INFINITY)) {   /* NaN or inf: an update that must not be taken */
            bdf->failed_non_finite = 1;
            break;
        }
        const double rate = dy_norm_old < 0.0 ? -1.0 : dy_norm / dy_norm_old;
        /* a correction already within Newton's tolerance ends it: its rate, from two such
         * corrections, would be round-off (at rest it is noise around 1) */
        const int small = dy_norm <= NEWTON_TOL;
        if (!small && rate >= 0.0 && (rate >= 1.0 || pow(rate, NEWTON_MAXITER - k)
                                      / (1.0 - rate) * dy_norm > NEWTON_TOL))
            break;
        for (int64_t i = 0; i < n; i++) {
            bdf->y[i] += bdf->dy[i];
            bdf->d[i] += bdf->dy[i];
        }
        if (small || (rate >= 0.0 && rate / (1.0 - rate) * dy_norm < NEWTON_TOL)) {
            *n_iter = k + 1;
            return 1;
        }
        dy_norm_old = dy_norm;
    }
    return 0;
}

/*
 * The first step of a new history at x with rates f (Hairer & Wanner's starting step, as
 * scipy's select_initial_step for an order-1 estimate): its scale the tolerance's (norm), its
 * interval the control period dt. Uses y, f0 and dy as scratch.
 */
static double first_step(ds_bdf *bdf, ds_group *group, const double *x, const double *f,
                         const double *u, double dt)
{
    const int64_t n = bdf->n;
    const double d0 = norm(bdf, x, 1.0), d1 = norm(bdf, f, 1.0);
    double h0 = d0 < 1e-5 || d1 < 1e-5 ? 1e-6 : 0.01 * d0 / d1;
    if (h0 > dt)
        h0 = dt;
    for (int64_t i = 0; i < n; i++)
        bdf->y[i] = x[i] + h0 * f[i];
    if (ds_rhs(group->m, bdf->y, u, bdf->f0, &group->w, 0) != DS_OK)
        return h0;
    for (int64_t i = 0; i < n; i++)
        bdf->dy[i] = bdf->f0[i] - f[i];
    const double d2 = norm(bdf, bdf->dy, 1.0) / h0;
    if (!isfinite(d2))   /* the rate at the trial point is not usable: its step */
        return h0;
    const double h1 = d1 <= 1e-15 && d2 <= 1e-15 ? fmax(1e-6, h0 * 1e-3)
                                                 : pow(0.01 / fmax(d1, d2), 0.5);
    return fmin(fmin(100.0 * h0, h1), dt);
}

/* A new history at x: order 1, the first step from the problem, no Jacobian. */
static int restart(ds_bdf *bdf, ds_group *group, const double *x, const double *u, double dt)
{
    const int64_t n = bdf->n;
    int status = ds_rhs(group->m, x, u, bdf->f, &group->w, 0);
    for (int64_t i = 0; i < n && status == DS_OK; i++)
        if (!isfinite(bdf->f[i]))
            status = DS_NON_FINITE;
    bdf->has_history = 0;
    if (status != DS_OK)
        return status;
    const double h_abs = first_step(bdf, group, x, bdf->f, u, dt);
    memset(bdf->D, 0, (size_t)(N_ROWS * n) * sizeof(double));
    memcpy(bdf->D, x, (size_t)n * sizeof(double));
    for (int64_t i = 0; i < n; i++)
        bdf->D[n + i] = bdf->f[i] * h_abs;
    bdf->h_abs = h_abs;
    bdf->order = 1;
    bdf->n_equal_steps = 0;
    bdf->has_jac = bdf->jac_is_current = 0;
    bdf->lu_c = 0.0;
    bdf->has_history = 1;
    return DS_OK;
}

/* The step's prediction y_predict = sum D[:order + 1] and psi, the history's part of the
 * formula: sum_k gamma_k D[k] / alpha_order. */
static void predict(ds_bdf *bdf)
{
    const int64_t n = bdf->n;
    const int order = bdf->order;
    const double alpha = bdf->alpha[order];
    for (int64_t i = 0; i < n; i++) {
        double y = 0.0, p = 0.0;
        for (int k = 0; k <= order; k++)
            y += bdf->D[k * n + i];
        for (int k = 1; k <= order; k++)
            p += bdf->D[k * n + i] * bdf->gamma[k];
        bdf->y_predict[i] = y;
        bdf->psi[i] = p / alpha;
    }
}

/*
 * One attempt at a step of h_abs with the current order (scipy's _step_impl up to its error
 * test): predict, Newton (a fresh Jacobian once if it failed with an old one), the error norm.
 * *outcome: STEP_ACCEPTED (*error_norm, *n_iter set), STEP_NEWTON_FAILED or
 * STEP_ERROR_FAILED. Returns a status only for what no smaller step can mend.
 */
static int try_step(ds_bdf *bdf, ds_group *group, const double *u, int *outcome,
                    double *error_norm, int *n_iter)
{
    const int order = bdf->order;
    const double c = bdf->h_abs / bdf->alpha[order];
    predict(bdf);
    int converged = 0;
    *n_iter = NEWTON_MAXITER;
    bdf->failed_non_finite = 0;
    for (;;) {
        if (!bdf->has_jac) {
            const int status = jacobian(bdf, group, bdf->y_predict, u);
            if (status == DS_NON_FINITE) {   /* a smaller step may avoid it */
                bdf->failed_non_finite = 1;
                break;
            }
            if (status != DS_OK)
                return status;
        }
        /* no LU yet (lu_c 0: c / 0 is inf), or one of a c too far off */
        if (fabs(c / bdf->lu_c - 1.0) > LU_KEEP && factorize(bdf, c) < 0)
            return DS_SINGULAR;
        converged = newton(bdf, group, u, c, n_iter);
        if (converged || bdf->jac_is_current)
            break;
        bdf->has_jac = 0;
    }
    if (!converged) {
        *outcome = STEP_NEWTON_FAILED;
        return DS_OK;
    }
    *error_norm = norm(bdf, bdf->d, bdf->error_const[order]);
    *outcome = *error_norm > 1.0 ? STEP_ERROR_FAILED : STEP_ACCEPTED;
    return DS_OK;
}

/* The step size factor safety * error_norm^(-1/(order + 1)) takes, with scipy's safety for the
 * Newton iterations the step took. */
static double safety(int n_iter)
{
    return 0.9 * (2 * NEWTON_MAXITER + 1) / (double)(2 * NEWTON_MAXITER + n_iter);
}

/* An accepted step into the history (scipy's difference update), and after order + 1 equal
 * steps the order and step size whose error estimate allows the largest step. */
static void accept_step(ds_bdf *bdf, double error_norm, int n_iter)
{
    const int64_t n = bdf->n;
    const int order = bdf->order;
    bdf->jac_is_current = 0;
    bdf->n_equal_steps += 1;
    for (int64_t i = 0; i < n; i++) {
        bdf->D[(order + 2) * n + i] = bdf->d[i] - bdf->D[(order + 1) * n + i];
        bdf->D[(order + 1) * n + i] = bdf->d[i];
    }
    for (int k = order; k >= 0; k--)
        for (int64_t i = 0; i < n; i++)
            bdf->D[k * n + i] += bdf->D[(k + 1) * n + i];
    if (bdf->n_equal_steps < order + 1)
        return;
    const double error_m = order > 1 ? norm(bdf, bdf->D + order * n, bdf->error_const[order - 1])
                                     : INFINITY;
    const double error_p = order < DS_BDF_MAX_ORDER
                           ? norm(bdf, bdf->D + (order + 2) * n, bdf->error_const[order + 1])
                           : INFINITY;
    const double error_norms[3] = {error_m, error_norm, error_p};
    int best = 0;
    double best_factor = -1.0;
    for (int k = 0; k < 3; k++) {
        const double factor = error_norms[k] > 0.0 ? pow(error_norms[k], -1.0 / (order + k))
                                                   : INFINITY;
        if (factor > best_factor) {
            best_factor = factor;
            best = k;
        }
    }
    bdf->order = order + best - 1;
    const double factor = fmin(MAX_FACTOR, safety(n_iter) * best_factor);
    change_step(bdf, factor, bdf->h_abs * factor);
}

/* Fit the step to whole steps of equal size in what is ``left`` of the period. A change
 * beyond round-off is a step-size change (the equal steps start anew, as at every change: the
 * differences past the order then hold one step size); the round-off of the steps after a fit
 * is not. */
static void fit_to_period(ds_bdf *bdf, double left)
{
    double n_left = ceil(left / bdf->h_abs - 1e-9);
    if (n_left < 1.0)
        n_left = 1.0;
    const double h_fit = left / n_left;
    if (h_fit == bdf->h_abs)
        return;
    const double factor = h_fit / bdf->h_abs;
    rescale(bdf, factor, h_fit);
    if (fabs(factor - 1.0) > FIT_ROUND_OFF)
        bdf->n_equal_steps = 0;
}

/* The steps of one control period: each fitted to what is left of it (whole steps of equal
 * size), tried, and on a failure retried smaller. */
static int period(const ds_stepper *stepper, ds_group *group, ds_bdf *bdf, const double *u)
{
    const double dt = stepper->dt;
    double t = 0.0;
    for (int64_t attempts = 0; dt - t > 1e-12 * dt; attempts++) {
        if (attempts == MAX_ATTEMPTS)   /* a state running away: fail, do not hang */
            return DS_NO_PROGRESS;
        fit_to_period(bdf, dt - t);
        const double h_abs = bdf->h_abs;
        if (!(h_abs > MIN_STEP_FRACTION * dt))
            return bdf->failed_non_finite ? DS_NON_FINITE : DS_STEP_UNDERFLOW;
        int outcome, n_iter;
        double error_norm = 0.0;
        const int status = try_step(bdf, group, u, &outcome, &error_norm, &n_iter);
        if (status != DS_OK)
            return status;
        group->steps += 1.0;
        if (outcome == STEP_NEWTON_FAILED) {
            bdf->rejected += 1;
            change_step(bdf, 0.5, bdf->h_abs * 0.5);
        } else if (outcome == STEP_ERROR_FAILED) {
            bdf->rejected += 1;
            const double factor = fmax(MIN_FACTOR, safety(n_iter)
                                                   * pow(error_norm, -1.0 / (bdf->order + 1)));
            change_step(bdf, factor, bdf->h_abs * factor);
        } else {
            t += h_abs;
            if (error_norm * bdf->tol > group->est)   /* the estimate of what was accepted */
                group->est = error_norm * bdf->tol;
            accept_step(bdf, error_norm, n_iter);
        }
    }
    return DS_OK;
}

int ds_bdf_period(const ds_stepper *stepper, ds_group *group, double *x, const double *u)
{
    ds_bdf *bdf = group->bdf;
    const int64_t n = bdf->n;
    int status = DS_OK;
    for (int64_t i = 0; i < n; i++)
        if (!isfinite(x[i]))
            return DS_NON_FINITE;
    /* the bookkeeping states may have been written from outside (an ideal source's recharge
     * booked at an input jump): a constant shift of their integral, not a new history */
    if (!bdf->has_history || memcmp(bdf->D, x, (size_t)bdf->n_core * sizeof(double)) != 0)
        status = restart(bdf, group, x, u, stepper->dt);
    else
        memcpy(bdf->D + bdf->n_core, x + bdf->n_core,
               (size_t)(n - bdf->n_core) * sizeof(double));
    if (status == DS_OK)
        status = period(stepper, group, bdf, u);
    for (int64_t i = 0; i < n && status == DS_OK; i++)   /* states outside the norm too */
        if (!isfinite(bdf->D[i]))
            status = DS_NON_FINITE;
    if (status != DS_OK) {   /* x is untouched: the steps run on the history D */
        bdf->has_history = 0;
        return status;
    }
    memcpy(x, bdf->D, (size_t)n * sizeof(double));
    return DS_OK;
}
