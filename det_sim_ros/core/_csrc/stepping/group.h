/*
 * The stepper's records (see physics/model.h for the kernel's layers): a model's stepper
 * (ds_stepper) and what each coupled group steps with (ds_group), shared by the stepping
 * units, each with its own header:
 *
 * stepper.h     the set-up: a model view and scratch per coupled group (stepper.c)
 * stages.h      n steps of the exponential Runge-Kutta stages on one group (stages.c)
 * period.h      one group's control period: charge transient, step-count controller
 *               (period.c)
 * batch.h       the whole model's control periods (groups one by one or over threads), runs
 *               (batch.c)
 * amp_period.h  an amplified period, split where a law of the amplifier switches
 * coupling.h    the charge's exact coupling to an amplifier output that follows its command
 * linear_part.h a dense linear part over the beams' q, qdot (with matrix_phi.h)
 * bdf.h         the variable-order BDF stepper, in place of the table's stages
 * kind.h        the kinds of stepper (stages, linearized, bdf): the one place they differ
 * method.h      the method table and the phi functions
 */
#ifndef DETSIM_STEPPING_GROUP_H
#define DETSIM_STEPPING_GROUP_H

#include "physics/model.h"
#include "stepping/method.h"

struct ds_linear;   /* linear_part.h */
struct ds_bdf;      /* bdf.h */
struct ds_kind;     /* kind.h */

/* The options of every kind of stepper in one record; a kind reads those its entry in kind.c
 * names. */
typedef struct {
    double refresh;          /* linearized: the weighted state change since the linear part
                                was taken that renews it */
    double refresh_input;    /* linearized: the input change that renews it, V (0: any) */
    double tolerance;        /* bdf: local error per step in its weighted norm */
    const double *weights;   /* bdf: its norm's 1 / scale per state (read at init only) */
} ds_kind_options;

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
    struct ds_linear *lin;              /* dense linear part over q, qdot (NULL: none) */
    struct ds_bdf *bdf;                 /* the BDF stepper's history (NULL: a table method) */
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

/* A model's stepper: the method and its kind, the transient settings and one ds_group per
 * coupled group. */
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
    const struct ds_kind *kind;         /* how each group steps (kind.h) */
    ds_kind_options options;            /* what the kind reads of them */
} ds_stepper;

#endif
