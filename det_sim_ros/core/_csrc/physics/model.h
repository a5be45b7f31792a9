/*
 * det_sim_ros compiled kernel: the model as named records (cells, DETs, the model, the
 * right-hand side's scratch). The kernel by layer, each include pointing down only:
 *
 * physics/   the model's equations: physics.h (right-hand side, stiff rates, input-jump
 *            bookkeeping; derived in det_sim_ros/physics/model.py, the same physics in
 *            readable numpy in det_sim_ros/physics/reference.py, which the tests hold this
 *            code to), outputs.h (the named outputs), exact.h (the exact kinematics'
 *            quadrature), amplifier.h (the amplifier's laws in the supply circuit)
 * stepping/  on physics: group.h (the stepper's records, ds_stepper and ds_group, which hold
 *            the stepping state), stepper.h (set-up), stages.h (the exponential Runge-Kutta
 *            stages), period.h (a group's control period), batch.h (the whole model's
 *            periods, runs), amp_period.h (an amplified period split where a law switches),
 *            coupling.h (the charge's exact coupling to an amplifier output), method.h,
 *            linear_part.h and matrix_phi.h (a dense linear part over the beams)
 * wire/      beside physics, the node's I/O path: frames.h (marker frames), wire.h (sample
 *            messages in CDR, MCAP message records), endian.h (the writers they share)
 * binding/   on all three: the Python types (buffer protocol only: no numpy C API)
 *
 * Units: SI throughout (m, kg, s, V, C, A, W, J).
 */
#ifndef DETSIM_PHYSICS_MODEL_H
#define DETSIM_PHYSICS_MODEL_H

#include <stdint.h>

/* Status codes (same values as det_sim_ros.core.kernel.OK ...; the user's text of each is
 * det_sim_ros/physics/model.py's). The last three are the BDF stepper's: its step size fell
 * below MIN_STEP_FRACTION of the period, it took MAX_ATTEMPTS steps in one period, or its
 * iteration matrix I - h/alpha J had a zero pivot (stepping/bdf.c). */
enum { DS_OK = 0, DS_BAD_STRETCH = 1, DS_NON_FINITE = 2, DS_BAD_SLOPE = 3,
       DS_STEP_UNDERFLOW = 4, DS_NO_PROGRESS = 5, DS_SINGULAR = 6 };

/* Kinematics level of a cell (scene fidelity). */
enum { KIN_PAPER = 0, KIN_CONSISTENT = 1, KIN_EXACT = 2 };

#define DS_CELL_OUTPUTS 9   /* q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E */
#define DS_MAX_CELL_NODES 72   /* quadrature nodes per cell (66 at 12 Ritz terms, exact) */

/* One beam pair ("cell"): its Ritz coordinates, quadrature nodes and beam constants. */
typedef struct {
    int64_t q0, nr;         /* first Ritz coordinate in q, number of terms */
    int64_t g0, g1;         /* quadrature nodes [g0, g1) in B1, B2, W */
    int64_t mass_col;       /* column of q0 in its group's mass block */
    int64_t group;          /* coupled group (cells coupled by the structure's inertia) */
    int kinematics;         /* KIN_PAPER, KIN_CONSISTENT or KIN_EXACT */
    double length;          /* beam length l, m */
    double EI;              /* bending stiffness, N m^2 */
    double kappa;           /* 1: the w'^4/8 end-shortening term (consistent), else 0 */
    /* one-term closed forms: 1/2 int S'^2, 1/8 int S'^4, EI int S''^2 S'^2 */
    double c2, c4, e4;
    double mi_self;         /* interface mass on its own end shortening, MI[c, c] (kg) */
} ds_cell;

/* The DET spanning a cell (eqs 53-57, 66-67) and its supply circuit. */
typedef struct {
    double l0, VY, C0, volume, E_M, eta_M, eta_v, Rs, Rp;
    /* derived once: the rhs multiplies instead of dividing */
    double inv_l0, inv_C0, inv_Rs, inv_Rp, share /* Rp/(Rs+Rp) */, relax_M /* E_M/eta_M */;
    /* the amplifier (0: off): output time constant 1/(2 pi bandwidth) (s), slew-rate limit
     * (V/s), current limit (A) */
    double amp_tau, amp_slew, amp_imax;
} ds_det;

/* A model (or one coupled group of a model: a view with local indices). */
typedef struct {
    int64_t n_q, n_cells, n_state, r_max, n_nodes, n_mi, n_groups, n_structure, mass_block;
    int creep, rc_source, power;
    int amp, amp_state;                /* an amplifier shapes the supply; its v_a are states */
    int one_term;                      /* one cell, one Ritz term, not exact: scalar rhs */
    int64_t i_eps, i_qp, i_va, i_power; /* offsets of eps_E, q_p, v_a, (W_in, W_diss) in x */
    ds_cell *cell;                     /* n_cells */
    ds_det *det;                       /* n_cells */
    const double *B1, *B2, *W;         /* S_j'(x_g), S_j''(x_g) (n_nodes x r_max), weights */
    const double *B1T, *B2T;           /* the same by cell transposed: S_j' of cell c at its
                                        * nodes from B1T[g0 r_max + j (g1 - g0)] (exact.c) */
    const double *Mb, *K, *D;          /* block rows by cell (n_q x r_max) */
    const double *Mb_inv;              /* each cell's block of Mb inverted (as Mb) */
    const double *mi_val;              /* interface mass entries MI[mi_row, mi_col] */
    int64_t *mi_row, *mi_col;
    int64_t *group_q;                  /* coordinate offsets of the coupled groups (n_groups+1) */
    const double *ref;                 /* S_j at the reference point (published deflection) */
    const double *P;                   /* structure outputs = P y (n_structure x n_cells) */
} ds_model;

/* Scratch of the right-hand side and outputs (one per model or group; not shared by threads). */
typedef struct {
    double *y, *h, *J, *F;             /* end shortenings, qd' H_y qd, dy/dq, forces */
    double *Mt;                        /* mass blocks (n_q x mass_block) */
    double *Us4, *ydot;                /* outputs: bending energy beyond EI int w''^2, dy/dt */
    double *dx;                        /* outputs: a rate buffer */
    double p_in, p_diss;               /* supplied and dissipated power of the last rhs, W */
    int *i_law, *v_law;                /* each DET's amplifier laws at the state of the last
                                        * ds_amp_laws on this scratch (amplifier.h) */
    int owned;                         /* the buffer is this scratch's (ds_work_init) */
    int64_t nan_after;                 /* a test's planted fault: the nan_after-th rhs from
                                        * now returns NaN in its first acceleration (0: none;
                                        * Stepper.plant_nan) */
    int nan_lasting;                   /* ... and every rhs after it */
} ds_work;

#endif
