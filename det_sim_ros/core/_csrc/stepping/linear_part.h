/*
 * A dense linear part over the mechanical states (the Ritz coordinates q and their rates):
 * the Jacobian A of the right-hand side there, taken at a control period's start state and kept
 * while the state stays near it (linear_part.c), and the weights of an exponential table for
 * x' = A x + N(x) per step size (phi_k(c h A) by scaling and squaring, matrix_phi.c). The
 * stiff, heavily damped beam modes are then integrated exactly and the step count follows the
 * error estimate instead of their decay rates.
 */
#ifndef DETSIM_LINEAR_PART_H
#define DETSIM_LINEAR_PART_H

#include "physics/model.h"
#include "stepping/group.h"
#include "stepping/matrix_phi.h"
#include "stepping/method.h"

/* step sizes whose weights are kept: a period's own and a charge transient's dyadic ones */
#define DS_LIN_SLOTS 8
#define DS_LIN_CHAINS 3  /* phi chains kept per A: the step-count ladder's odd factors 1, 3, 5 */

/* The weights of one step size: phi_0(c_i h A) (rows 0..s) and the table's merged
 * (row, stage) weights sum_t w_t phi_{k_t}(c_t h A), each nd x nd. */
typedef struct {
    double h;                           /* 0: empty */
    double *E, *W;
} ds_lin_slot;

typedef struct ds_linear {
    int64_t nd;                         /* linearised states: q, qdot (2 n_q) */
    int64_t n_pairs;                    /* merged (row, stage) pairs of the table */
    int64_t *pair_start, *pair_stage;   /* row i: pairs pair_start[i] .. [i + 1] */
    int64_t est_pair;                   /* pair (row s, stage s-1): the estimate's weights */
    double est_scale;                   /* 1 / that pair's weight at A = 0 */
    double *A;                          /* nd x nd, row-major */
    double *x_lin, *u_lin;              /* the state (nd) and input where A was taken */
    int valid;
    int q_rates;                        /* A's q rows are [0 I] (q' = qdot): the remainder
                                           N is 0 there, bit for bit, and is skipped */
    int64_t next_slot, refreshes, fills;   /* Jacobians taken, weight sets computed */
    int64_t chain_builds;               /* phi chains built anew (the rest were doublings) */
    ds_lin_slot slot[DS_LIN_SLOTS];
    ds_phi_chain chain[DS_LIN_CHAINS];  /* of the current A (matrix_phi.h) */
    double *phis;                       /* per table argument: phi_0..k_max, full and half */
    double *work, *xq, *f0, *f1;
    double *mem;                        /* the doubles above, one allocation */
} ds_linear;

int ds_linear_init(ds_linear *lin, const ds_method *me, const ds_model *m);
void ds_linear_free(ds_linear *lin);
void ds_linear_reset(ds_linear *lin);
/* Take A at the group's state x and input u when it is invalid or the state left it. */
int ds_linear_update(const ds_stepper *st, ds_group *g, const double *x, const double *u);
/* The weights of step size h: a kept slot, or the next slot in turn filled anew (never
 * ``keep``, the last step's). */
const ds_lin_slot *ds_linear_weights(const ds_method *me, ds_linear *lin, double h,
                                     const ds_lin_slot *keep);

#endif
