/*
 * The stepper (see physics/model.h for the kernel's layers):
 *
 * stages.c   n steps of the exponential Runge-Kutta stages on one group (ds_advance)
 * stepping.c one group's control period: charge transient, step-count controller
 * stepper.c  the stepper's set-up: a model view and scratch per coupled group
 * batch.c    the whole model's control periods (groups one by one or over threads), runs
 *
 * with the units it steps through: method.h (the method table, phi functions),
 * linear_part.h and matrix_phi.h (a dense linear part over the beams' q, qdot), coupling.h
 * (the charge's exact coupling to an amplifier output that follows its command) and
 * amp_period.h (an amplified period split where a law switches).
 */
#ifndef DETSIM_STEPPING_H
#define DETSIM_STEPPING_H

#include "physics/model.h"
#include "stepping/linear_part.h"
#include "stepping/method.h"

/* The transients of one DET in an amplified control period (amp_period.c): the charge's and
 * the output's last transient (start time in the period, s; time constant, s; size, V). */
typedef struct {
    double charge_t0, charge_tau, charge_dv, output_t0, output_dv;
} ds_amp_transient;

/* Step-count controller of one group (fixed when tol <= 0). */
typedef struct {
    int64_t n, n_min, n_max;
    double tol, exponent;
} ds_control;

/* Everything one group needs to step: a model view, its scratch and its step-count controller.
 * A model whose cells form one coupled group steps as a whole (the view is the model itself);
 * independent groups (an array of actuators) each step with their own count, so one copy
 * snapping does not force its count on the others. */
typedef struct ds_group {
    ds_model *m;                        /* the group's model (the whole model if one group) */
    ds_model view;                      /* storage of m when the model has several groups */
    ds_work w;
    ds_control ctl, ctl_initial;
    double est, steps;                  /* largest error estimate since reset, steps taken */
    double watched;                     /* amplified periods stepped one step at a time for a
                                           current limit within reach (amp_period.c) */
    double repeated;                    /* periods repeated with more steps (estimate over
                                           the tolerance, or the domain left) */
    int64_t s0, s1;                     /* states with a stiff rate: [s0, s1) */
    int64_t q_first, c_first;           /* first coordinate and cell in the whole model */
    int quasi_static;
    ds_linear *lin;                     /* dense linear part over q, qdot (NULL: none) */
    double *cpl;                        /* the charge's coupling to v_a (coupling.c; NULL:
                                           none) */
    int status;                         /* of the last period (batch) */
    ds_amp_transient *transient;        /* per cell, with an amplifier (NULL: none) */
    /* stepping scratch (one allocation) */
    double *N, *X, *L, *e_c, *x_start, *pend, *x0, *x_keep, *phis, *coef, *inv_scale, *x_local;
    ds_cell *view_cells;
    int64_t *view_ints;
    double *view_mi;
} ds_group;

/* A model's stepper: the method, the transient settings and one ds_group per coupled group. */
typedef struct ds_stepper {
    const ds_model *model;
    ds_method method;
    double dt;                          /* control period, s */
    double z_tol;                       /* charge lag that counts as a transient, C (0: off) */
    double fine;                        /* first step after an input jump, units of tau */
    double jump_ref;                    /* the input jump (V) ``fine`` is sized for: a smaller
                                           jump du starts at fine (jump_ref/du)^(1/5) (0: every
                                           jump at fine) */
    int64_t n_groups;
    ds_group *group;
    double *arena;                      /* every group's scratch, in group order (locality) */
    int threads;
    int linearized;                     /* a dense linear part over q, qdot per group */
    double lin_refresh;                 /* weighted state change that renews it */
    double lin_refresh_input;           /* input change (V) that renews it (0: any) */
} ds_stepper;

/* st->method must be initialised (ds_method_init) before. */
int ds_stepper_init(ds_stepper *st, const ds_model *m, double dt, double z_tol, double fine,
                    const ds_control *ctl, const double *inv_scale);
void ds_stepper_free(ds_stepper *st);
int ds_advance(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
               int64_t n_steps, double growth);
int ds_period(ds_stepper *st, double *x, const double *u_old, const double *u);
/* One control period of one group (stepping.c); ds_period runs it for each group. */
int ds_period_core(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                   const double *u);
void ds_reset_control(ds_stepper *st);
int ds_run(ds_stepper *st, ds_work *ow, double *x, const double *u_held, const double *u_last,
           const double *U, int64_t n, double *X, double *Y, int64_t *done);

#endif
