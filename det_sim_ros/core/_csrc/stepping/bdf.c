/*
 * The variable-order BDF stepper (bdf.h): the numerical differentiation formulas of orders 1-5
 * with a quasi-constant step (Shampine & Reichelt, SIAM J. Sci. Comput. 18, 1997; the scheme
 * of scipy's integrate/_ivp/bdf.py), the history as backward differences D, a simplified
 * Newton iteration with the Jacobian kept while it converges. Each period's steps fit it
 * evenly, so the state at its end is the method's own and an input that changes there starts
 * the next step from it. det_sim_ros/physics/reference_bdf.py documents the choices.
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

static const double KAPPA[DS_BDF_MAX_ORDER + 1] = {0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415,
                                                   0.0};

/* gamma_k = sum_{j=1..k} 1/j, alpha_k = (1 - kappa_k) gamma_k and the error constants
 * kappa_k gamma_k + 1/(k+1), summed as numpy's cumsum does. */
static void tables(ds_bdf *b)
{
    double g = 0.0;
    for (int k = 0; k <= DS_BDF_MAX_ORDER; k++) {
        if (k > 0)
            g += 1.0 / (double)k;
        b->gamma[k] = g;
        b->alpha[k] = (1.0 - KAPPA[k]) * g;
        b->error_const[k] = KAPPA[k] * g + 1.0 / (double)(k + 1);
    }
}

int ds_bdf_init(ds_bdf *b, int64_t n, int64_t n_core, const double *weights, double tol,
                double h0)
{
    memset(b, 0, sizeof(*b));
    b->n = n;
    b->n_core = n_core;
    b->tol = tol;
    b->h0 = h0;
    const int64_t total = N_ROWS * n + 4 * n * n + 9 * n;
    double *mem = calloc((size_t)total, sizeof(double));
    b->piv = calloc((size_t)n, sizeof(int64_t));
    if (!mem || !b->piv) {
        free(mem);
        free(b->piv);
        b->piv = NULL;
        return -1;
    }
    b->mem = mem;
    b->D = mem;
    b->J = b->D + N_ROWS * n;
    b->LU = b->J + n * n;
    b->LT = b->LU + n * n;
    b->w = b->LT + n * n;
    b->y_pred = b->w + n;
    b->psi = b->y_pred + n;
    b->y = b->psi + n;
    b->d = b->y + n;
    b->dy = b->d + n;
    b->f = b->dy + n;
    b->f0 = b->f + n;
    b->xp = b->f0 + n;
    memcpy(b->w, weights, (size_t)n * sizeof(double));
    tables(b);
    return 0;
}

void ds_bdf_free(ds_bdf *b)
{
    free(b->mem);
    free(b->piv);
    memset(b, 0, sizeof(*b));
}

void ds_bdf_reset(ds_bdf *b)
{
    b->valid = 0;
}

/* The weighted max norm over the tolerance; NaN if any component is NaN (numpy's max): a
 * NaN must fail every test it enters, never be skipped by a comparison. */
static double norm(const ds_bdf *b, const double *v, double scale)
{
    double m = 0.0;
    for (int64_t i = 0; i < b->n_core; i++) {
        const double e = fabs(scale * v[i]) * b->w[i];
        if (e > m || e != e)
            m = e;
        if (m != m)
            return m;
    }
    return m / b->tol;
}

/* D[:order + 1] = RU^T D[:order + 1] for a step factor (RU = R(factor) R(1)); h to h_new. */
static void rescale(ds_bdf *b, double factor, double h_new)
{
    const int o = b->order, m = o + 1;
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
    const int64_t n = b->n;
    double *tmp = b->xp;   /* free outside the Jacobian */
    for (int64_t c = 0; c < n; c++) {
        for (int j = 0; j < m; j++) {
            double s = 0.0;
            for (int i = 0; i < m; i++)
                s += RU[i][j] * b->D[i * n + c];
            tmp[j] = s;
        }
        for (int j = 0; j < m; j++)
            b->D[j * n + c] = tmp[j];
    }
    b->h = h_new;
}

/* LU with partial pivoting of I - c J into b->LU. Returns 0, or -1 when singular. */
static int factorize(ds_bdf *b, double c)
{
    const int64_t n = b->n_core;
    double *a = b->LU;
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++)
            a[i * n + j] = (i == j ? 1.0 : 0.0) - c * b->J[i * n + j];
    for (int64_t k = 0; k < n; k++) {
        int64_t p = k;
        for (int64_t i = k + 1; i < n; i++)
            if (fabs(a[i * n + k]) > fabs(a[p * n + k]))
                p = i;
        b->piv[k] = p;
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
            b->LT[j * n + i] = a[i * n + j];
    b->factorizations += 1;
    b->lu_c = c;
    return 0;
}

/* v = (I - c J)^-1 v with the factors, column by column from their transpose LT: each
 * column's update is independent across rows (no chain of dependent sums per row). */
static void solve(const ds_bdf *b, double *v)
{
    const int64_t n = b->n_core;
    const double *lt = b->LT;
    for (int64_t k = 0; k < n; k++) {
        const int64_t p = b->piv[k];
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
 * the bookkeeping states' rows after it. */
static int jacobian(ds_bdf *b, ds_group *g, const double *x, const double *u)
{
    const int64_t n = b->n_core;
    int status = ds_rhs(g->m, x, u, b->f0, &g->w, 0);
    memcpy(b->xp, x, (size_t)b->n * sizeof(double));
    for (int64_t j = 0; j < n && status == DS_OK; j++) {
        const double scale = b->w[j] > 0.0 ? 1.0 / b->w[j] : 1.0;
        const double size = fabs(x[j]) > scale ? fabs(x[j]) : scale;
        b->xp[j] = x[j] + FD_RELATIVE * size;
        const double step = b->xp[j] - x[j];
        status = ds_rhs(g->m, b->xp, u, b->f, &g->w, 0);
        b->xp[j] = x[j];
        for (int64_t i = 0; i < b->n; i++)   /* the bookkeeping rows after the core block */
            b->J[i < n ? i * n + j : n * n + (i - n) * n + j] = (b->f[i] - b->f0[i]) / step;
    }
    b->jacobians += 1;
    if (b->nan_after > 0 && --b->nan_after == 0) {   /* a planted fault (tests only) */
        b->J[0] = NAN;
        b->nan_after = b->nan_lasting;
    }
    b->lu_c = 0.0;   /* the LU is of the old J */
    int finite = 1;
    for (int64_t k = 0; k < b->n * n; k++)
        finite &= isfinite(b->J[k]);
    b->have_jac = finite;   /* a non-finite J is never kept */
    b->jac_current = 1;
    if (status == DS_OK && !finite)
        status = DS_NON_FINITE;
    return status;
}

/* The simplified Newton iteration of one step: y (from y_pred), d = y - y_pred. Returns 1 when
 * it converged, with *iters the iterations it took. The bookkeeping states (past n_core) no
 * rate reads make I - c J block lower triangular: the core's block is solved alone (the same
 * arithmetic with or without them) and their rows by substitution after it. */
static int newton(ds_bdf *b, ds_group *g, const double *u, double c, int *iters)
{
    const int64_t n = b->n;
    memcpy(b->y, b->y_pred, (size_t)n * sizeof(double));
    memset(b->d, 0, (size_t)n * sizeof(double));
    double old = -1.0;
    for (int k = 0; k < NEWTON_MAXITER; k++) {
        if (ds_rhs(g->m, b->y, u, b->f, &g->w, 0) != DS_OK)
            break;
        int finite = 1;
        for (int64_t i = 0; i < n; i++)
            finite &= isfinite(b->f[i]);
        if (!finite) {
            b->failed_non_finite = 1;
            break;
        }
        for (int64_t i = 0; i < n; i++)
            b->dy[i] = c * b->f[i] - b->psi[i] - b->d[i];
        solve(b, b->dy);
        const int64_t nc = b->n_core;
        for (int64_t i = nc; i < n; i++) {   /* the bookkeeping rows: -c J_bc dy_c + dy_b */
            const double *row = b->J + nc * nc + (i - nc) * nc;
            double s = 0.0;
            for (int64_t j = 0; j < nc; j++)
                s += row[j] * b->dy[j];
            b->dy[i] += b->lu_c * s;
        }
        const double size = norm(b, b->dy, 1.0);
        if (!(size < INFINITY)) {   /* NaN or inf: an update that must not be taken */
            b->failed_non_finite = 1;
            break;
        }
        const double rate = old < 0.0 ? -1.0 : size / old;
        /* a correction already within Newton's tolerance ends it: its rate, from two such
         * corrections, would be round-off (at rest it is noise around 1) */
        const int small = size <= NEWTON_TOL;
        if (!small && rate >= 0.0 && (rate >= 1.0 || pow(rate, NEWTON_MAXITER - k)
                                      / (1.0 - rate) * size > NEWTON_TOL))
            break;
        for (int64_t i = 0; i < n; i++) {
            b->y[i] += b->dy[i];
            b->d[i] += b->dy[i];
        }
        if (small || (rate >= 0.0 && rate / (1.0 - rate) * size < NEWTON_TOL)) {
            *iters = k + 1;
            return 1;
        }
        old = size;
    }
    return 0;
}

static int restart(ds_bdf *b, ds_group *g, const double *x, const double *u)
{
    const int64_t n = b->n;
    memset(b->D, 0, (size_t)(N_ROWS * n) * sizeof(double));
    memcpy(b->D, x, (size_t)n * sizeof(double));
    int status = ds_rhs(g->m, x, u, b->f, &g->w, 0);
    for (int64_t i = 0; i < n; i++) {
        b->D[n + i] = b->f[i] * b->h0;
        if (status == DS_OK && !isfinite(b->f[i]))
            status = DS_NON_FINITE;
    }
    b->h = b->h0;
    b->order = 1;
    b->equal_steps = 0;
    b->have_jac = b->jac_current = 0;
    b->lu_c = 0.0;
    b->valid = status == DS_OK;
    return status;
}

static int period(const ds_stepper *st, ds_group *g, ds_bdf *b, const double *u)
{
    const int64_t n = b->n;
    const double dt = st->dt;
    double t = 0.0;
    for (int64_t attempts = 0; dt - t > 1e-12 * dt; attempts++) {
        if (attempts == MAX_ATTEMPTS)   /* a state running away: fail, do not hang */
            return DS_NO_PROGRESS;
        const double left = dt - t;
        double n_left = ceil(left / b->h - 1e-9);
        if (n_left < 1.0)
            n_left = 1.0;
        if (left / n_left != b->h)
            rescale(b, left / n_left / b->h, left / n_left);
        const int order = b->order;
        const double h = b->h;
        if (!(h > MIN_STEP_FRACTION * dt))
            return b->failed_non_finite ? DS_NON_FINITE : DS_STEP_UNDERFLOW;
        const double a_k = b->alpha[order];
        for (int64_t i = 0; i < n; i++) {
            double s = 0.0, p = 0.0;
            for (int k = 0; k <= order; k++)
                s += b->D[k * n + i];
            for (int k = 1; k <= order; k++)
                p += b->D[k * n + i] * b->gamma[k];
            b->y_pred[i] = s;
            b->psi[i] = p / a_k;
        }
        const double c = h / a_k;
        int converged = 0, iters = NEWTON_MAXITER;
        b->failed_non_finite = 0;
        for (;;) {
            if (!b->have_jac) {
                const int status = jacobian(b, g, b->y_pred, u);
                if (status == DS_NON_FINITE) {   /* a smaller step may avoid it */
                    b->failed_non_finite = 1;
                    break;
                }
                if (status != DS_OK)
                    return status;
            }
            /* no LU yet (lu_c 0: c / 0 is inf), or one of a c too far off */
            if (fabs(c / b->lu_c - 1.0) > LU_KEEP && factorize(b, c) < 0)
                return DS_SINGULAR;
            converged = newton(b, g, u, c, &iters);
            if (converged || b->jac_current)
                break;
            b->have_jac = 0;
        }
        g->steps += 1.0;
        if (!converged) {
            b->rejected += 1;
            rescale(b, 0.5, b->h * 0.5);
            b->equal_steps = 0;
            continue;
        }
        const double safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (double)(2 * NEWTON_MAXITER + iters);
        const double error = norm(b, b->d, b->error_const[order]);
        if (error * b->tol > g->est)
            g->est = error * b->tol;
        if (error > 1.0) {
            b->rejected += 1;
            const double f = fmax(MIN_FACTOR, safety * pow(error, -1.0 / (order + 1)));
            rescale(b, f, b->h * f);
            b->equal_steps = 0;
            continue;
        }
        b->jac_current = 0;
        t += h;
        b->equal_steps += 1;
        for (int64_t i = 0; i < n; i++) {
            b->D[(order + 2) * n + i] = b->d[i] - b->D[(order + 1) * n + i];
            b->D[(order + 1) * n + i] = b->d[i];
        }
        for (int k = order; k >= 0; k--)
            for (int64_t i = 0; i < n; i++)
                b->D[k * n + i] += b->D[(k + 1) * n + i];
        if (b->equal_steps < order + 1)
            continue;
        const double lower = order > 1 ? norm(b, b->D + order * n, b->error_const[order - 1])
                                        : INFINITY;
        const double higher = order < DS_BDF_MAX_ORDER
                              ? norm(b, b->D + (order + 2) * n, b->error_const[order + 1])
                              : INFINITY;
        const double errs[3] = {lower, error, higher};
        int best = 0;
        double best_f = -1.0;
        for (int k = 0; k < 3; k++) {
            const double f = errs[k] > 0.0 ? pow(errs[k], -1.0 / (order + k)) : INFINITY;
            if (f > best_f) {
                best_f = f;
                best = k;
            }
        }
        b->order = order + best - 1;
        const double f = fmin(MAX_FACTOR, safety * best_f);
        rescale(b, f, b->h * f);
        b->equal_steps = 0;
    }
    return DS_OK;
}

int ds_bdf_period(const ds_stepper *st, ds_group *g, double *x, const double *u)
{
    ds_bdf *b = g->bdf;
    const int64_t n = b->n;
    int status = DS_OK;
    for (int64_t i = 0; i < n; i++)
        if (!isfinite(x[i]))
            return DS_NON_FINITE;
    /* the bookkeeping states may have been written from outside (an ideal source's recharge
     * booked at an input jump): a constant shift of their integral, not a new history */
    if (!b->valid || memcmp(b->D, x, (size_t)b->n_core * sizeof(double)) != 0)
        status = restart(b, g, x, u);
    else
        memcpy(b->D + b->n_core, x + b->n_core, (size_t)(n - b->n_core) * sizeof(double));
    if (status == DS_OK)
        status = period(st, g, b, u);
    for (int64_t i = 0; i < n && status == DS_OK; i++)   /* states outside the norm too */
        if (!isfinite(b->D[i]))
            status = DS_NON_FINITE;
    if (status != DS_OK) {   /* x is untouched: the steps run on the history D */
        b->valid = 0;
        return status;
    }
    memcpy(x, b->D, (size_t)n * sizeof(double));
    return DS_OK;
}
