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
    double tol;                 /* local error per step in the weighted norm */
    int has_history;            /* a history to go on from (else the next period restarts) */
    int order;                  /* of the formula the next step takes, 1..DS_BDF_MAX_ORDER */
    int n_equal_steps;          /* steps accepted since the step size last changed */
    int jac_is_current;         /* J was taken at this step's prediction */
    int has_jac;                /* J holds a Jacobian (finite) */
    double h_abs;               /* the step the differences D are scaled to, s */
    double lu_c;                /* the c = h_abs / alpha[order] the LU was factored at (0: no
                                   LU) */
    double *D;                  /* (DS_BDF_MAX_ORDER + 3) x n backward differences */
    double *J;                  /* df/dx: n_core x n_core, then the bookkeeping rows */
    double *LU, *LT;            /* LU of I - c J (n_core square) and its transpose */
    double *w;                  /* the norm's 1 / scale per state */
    int64_t *piv;
    double *y_predict, *psi;    /* this step's prediction, and the history's part of it */
    double *y, *d, *dy;         /* Newton's iterate, its distance from the prediction, its
                                   last correction */
    double *f, *f0, *xp;        /* rates; the Jacobian's base rates and perturbed state */
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
int ds_bdf_init(ds_bdf *bdf, int64_t n, int64_t n_core, const double *weights, double tol);
void ds_bdf_free(ds_bdf *bdf);
/* Forget the history: the next period restarts at order 1 with a first step chosen from the
 * problem (Hairer & Wanner's starting step, as scipy's select_initial_step). */
void ds_bdf_reset(ds_bdf *bdf);
/* One control period st->dt from x (in place) with the input u held. Returns a status that
 * names the failure (DS_NON_FINITE: a NaN or inf in the state, its rate or the Jacobian that
 * no smaller step avoided; DS_STEP_UNDERFLOW, DS_NO_PROGRESS, DS_SINGULAR; a domain status of
 * the right-hand side); on failure x holds its start and the history is forgotten. */
int ds_bdf_period(const ds_stepper *stepper, ds_group *group, double *x, const double *u);

#endif
