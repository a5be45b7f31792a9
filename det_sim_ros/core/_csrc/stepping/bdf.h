/*
 * A variable-order BDF stepper for one coupled group (bdf.c): the numerical differentiation
 * formulas of orders 1-5 with a quasi-constant step, driven one control period at a time.
 * det_sim_ros/physics/reference_bdf.py is the same in numpy; test/test_bdf.py holds this code
 * to it.
 */
#ifndef DETSIM_STEPPING_BDF_H
#define DETSIM_STEPPING_BDF_H

#include "stepping/group.h"

#define DS_BDF_MAX_ORDER 5

typedef struct ds_bdf {
    int64_t n;                  /* states (the whole group's) */
    int64_t n_core;             /* the leading states the Newton iteration, the norm and the
                                   restart test hold; the rest are bookkeeping integrals (the
                                   power monitor's W_in, W_diss) no rate reads: stepped with
                                   the same formula, outside the iteration matrix, so they
                                   never steer the steps */
    double tol, h0;             /* local error per step in the weighted norm; first step, s */
    int valid;                  /* a history to go on from (else the next period restarts) */
    int order, equal_steps, jac_current, have_jac;
    double h;                   /* the step the differences D are scaled to, s */
    double lu_c;                /* the c = h / alpha the LU was factored at (0: no LU) */
    double *D;                  /* (DS_BDF_MAX_ORDER + 3) x n backward differences */
    double *J, *LU, *LT, *w;    /* Jacobian, LU of I - c J and its transpose, the norm's
                                   1 / scale */
    int64_t *piv;
    double *y_pred, *psi, *y, *d, *dy, *f, *f0, *xp;
    double gamma[DS_BDF_MAX_ORDER + 1], alpha[DS_BDF_MAX_ORDER + 1];
    double error_const[DS_BDF_MAX_ORDER + 1];
    int64_t jacobians, factorizations, rejected;
    int failed_non_finite;      /* the last failed attempt met a NaN or inf (its status if
                                   the step then underflows) */
    int64_t nan_after;          /* a test's planted fault: the nan_after-th Jacobian from now
                                   gets a NaN (0: none; Stepper.plant_nan) */
    int nan_lasting;            /* ... and every Jacobian after it */
    void *mem;
} ds_bdf;

/* weights: 1 / scale per state of the group (n_core of them in the norm). Returns -1 without
 * memory. */
int ds_bdf_init(ds_bdf *b, int64_t n, int64_t n_core, const double *weights, double tol,
                double h0);
void ds_bdf_free(ds_bdf *b);
/* Forget the history: the next period restarts at order 1 with the first step. */
void ds_bdf_reset(ds_bdf *b);
/* One control period st->dt from x (in place) with the input u held. Returns a status that
 * names the failure (DS_NON_FINITE: a NaN or inf in the state, its rate or the Jacobian that
 * no smaller step avoided; DS_STEP_UNDERFLOW, DS_NO_PROGRESS, DS_SINGULAR; a domain status of
 * the right-hand side); on failure x holds its start and the history is forgotten. */
int ds_bdf_period(const ds_stepper *st, ds_group *g, double *x, const double *u);

#endif
