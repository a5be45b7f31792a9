/*
 * The stepping core (see detsim.h for the kernel's files):
 *
 * method.c   a method's coefficient table decoded (ds_method) and the phi functions
 * stages.c   n steps of the exponential Runge-Kutta stages on one group (ds_advance)
 * stepping.c one group's control period: charge transient, step-count controller
 * stepper.c  the stepper's set-up: a model view and scratch per coupled group
 * batch.c    the whole model's control periods (groups one by one or over threads), runs
 * linear_part.c, matrix_phi.c  a dense linear part over the beams' q, qdot (linear_part.h)
 * coupling.c the charge's exact coupling to an amplifier output that follows its command
 */
#ifndef DETSIM_STEPPING_H
#define DETSIM_STEPPING_H

#include "physics/detsim.h"
#include "stepping/linear_part.h"

/* A method table decoded for the core (see det_sim_ros/sim/integrators.py; method.c). */
typedef struct {
    int64_t n_stages, n_terms, n_args, k_max, n_embedded, exponential;
    double *c;                          /* stage nodes (n_stages) */
    int64_t *term_stage, *term_phi;     /* per term: stage j of N_j, phi index (-1: constant) */
    double *term_weight;
    int64_t *term_arg;                  /* index of the term's phi argument in args */
    double *args;                       /* distinct phi arguments c_arg */
    int64_t *row_start;                 /* terms of stage row i: row_start[i] .. [i+1] */
    int64_t *ec_arg;                    /* exp(c_i z) = phi_0 of args[ec_arg[i]] (-1: none) */
    double *coef0;                      /* term weights at L = 0 */
    int64_t *merged_start, *merged_stage; /* the L = 0 table, equal (row, stage) merged */
    int64_t n_exp_terms, *exp_term;     /* the terms with a phi weight (term_phi >= 0) */
    int64_t *exp_phi_at;                /* their phi_k(c_arg z) in a step's phis */
    double *merged_weight;
    double *embedded;                   /* e_0..e_s of the error estimate (n_embedded) */
} ds_method;

int ds_method_init(ds_method *me, const double *c, int64_t n_stages, const double *terms,
                   int64_t n_terms, const double *embedded, int64_t n_embedded);
void ds_method_free(ds_method *me);

/* out[k] = phi_k(z) for k = 0..n-1: the functions an exponential method's weights are made of
 * (method.c). */
void ds_phi_all(double z, double *out, int64_t n);

/* Step-count controller of one group (fixed when tol <= 0). */
typedef struct {
    int64_t n, n_min, n_max;
    double tol, exponent;
} ds_control;

/* Everything one group needs to step: a model view, its scratch and its step-count controller.
 * A model whose cells form one coupled group steps as a whole (the view is the model itself);
 * independent groups (an array of actuators) each step with their own count, so one copy
 * snapping does not force its count on the others. */
typedef struct {
    ds_model *m;                        /* the group's model (the whole model if one group) */
    ds_model view;                      /* storage of m when the model has several groups */
    ds_work w;
    ds_control ctl, ctl_initial;
    double est, steps;                  /* largest error estimate since reset, steps taken */
    double watched;                     /* amplified periods stepped one step at a time for a
                                           current limit within reach (amplifier.c) */
    double repeated;                    /* periods repeated with more steps (estimate over
                                           the tolerance, or the domain left) */
    int64_t s0, s1;                     /* states with a stiff rate: [s0, s1) */
    int64_t q_first, c_first;           /* first coordinate and cell in the whole model */
    int quasi_static;
    ds_linear *lin;                     /* dense linear part over q, qdot (NULL: none) */
    double *cpl;                        /* the charge's coupling to v_a (coupling.c; NULL:
                                           none) */
    int status;                         /* of the last period (batch) */
    /* stepping scratch (one allocation) */
    double *N, *X, *L, *e_c, *x_start, *pend, *x0, *x_keep, *phis, *coef, *inv_scale, *x_local;
    ds_cell *view_cells;
    int64_t *view_ints;
    double *view_mi;
} ds_group;

/* A model's stepper: the method, the transient settings and one ds_group per coupled group. */
typedef struct {
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
/* linear_part.c: the dense linear part of a group (see linear_part.h) */
int ds_linear_init(ds_linear *lin, const ds_method *me, const ds_model *m);
void ds_linear_free(ds_linear *lin);
void ds_linear_reset(ds_linear *lin);
int ds_linear_update(const ds_stepper *st, ds_group *g, const double *x, const double *u);
const ds_lin_slot *ds_linear_weights(const ds_method *me, ds_linear *lin, double h,
                                     const ds_lin_slot *keep);
/* One control period of one group of an amplified model (amplifier.c): steps of at most h
 * (n_sub of them without switches), split where a law of the amplifier switches. */
int ds_amp_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                  const double *u, double h, int64_t n_sub);
/* coupling.c: the charge's exact coupling to a following amplifier output (stages.c calls
 * these where g->cpl is set) */
int64_t ds_coupling_size(const ds_method *me);
int ds_coupling_fits(const ds_method *me);
void ds_coupling_weights(const ds_method *me, ds_group *g, double h);
void ds_coupling_row(const ds_method *me, const ds_group *g, int64_t row, const double *x,
                     const double *N, double h, double *X);
void ds_coupling_remainder(const ds_method *me, const ds_group *g, const double *X, double *N);
int ds_run(ds_stepper *st, ds_work *ow, double *x, const double *u_held, const double *u_last,
           const double *U, int64_t n, double *X, double *Y, int64_t *done);

#endif
