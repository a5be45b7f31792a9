/*
 * det_sim_ros compiled kernel: the model as named records and its physics. The kernel's files:
 *
 * amplifier.c    the high-voltage amplifier in the supply circuit: its laws (bandwidth, slew
 *                rate, current limit) and the control period that locates their switches
 * physics.c      right-hand side, stiff rates, input-jump bookkeeping (the equations are
 *                derived and documented in det_sim_ros/physics/model.py;
 *                det_sim_ros/physics/reference.py is the same physics in readable numpy, and
 *                the tests hold this code to it); outputs.c the named outputs; exact.c
 *                the exact kinematics' quadrature
 * stepping.h     the stepping core: method.c (method tables and the phi functions), stages.c
 *                (the exponential Runge-Kutta stages), stepping.c (one group's control period:
 *                charge transients, step-count controller), stepper.c (set-up of the per-group
 *                steppers), batch.c (the whole model's periods and offline runs),
 *                linear_part.h (a dense linear part over the beams: linear_part.c,
 *                matrix_phi.c)
 * wire.h         the node's I/O path, not physics: frames.c (marker frames of one-coordinate
 *                cells) and wire.c (sample messages in CDR, MCAP message records)
 * binding.h      the Python binding (buffer protocol only: no numpy C API, no ABI coupling)
 *
 * Units: SI throughout (m, kg, s, V, C, A, W, J).
 */
#ifndef DETSIM_H
#define DETSIM_H

#include <stdint.h>

/* Status codes (same values as det_sim_ros.core.kernel.OK ...). */
enum { DS_OK = 0, DS_BAD_STRETCH = 1, DS_NON_FINITE = 2, DS_BAD_SLOPE = 3 };

/* Kinematics level of a cell (scene fidelity). */
enum { KIN_PAPER = 0, KIN_CONSISTENT = 1, KIN_EXACT = 2 };

#define DS_CELL_OUTPUTS 9   /* q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E */
#define DS_MAX_CELL_NODES 64   /* quadrature nodes per cell (62 at 12 Ritz terms, exact) */

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

/* The laws the amplifier follows during one step (amplifier.c sets them at each step's start):
 * its output current, linear (through Rs) or at the limit, and its output voltage v_a. */
enum { AMP_LINEAR = 0, AMP_LIMIT_POS = 1, AMP_LIMIT_NEG = 2 };
enum { VA_FOLLOW = 0, VA_SLEW_UP = 1, VA_SLEW_DOWN = 2, VA_HOLD = 3 };

/* The DET spanning a cell (eqs 53-57, 66-67) and its supply circuit. */
typedef struct {
    double l0, VY, C0, volume, E_M, eta_M, eta_v, Rs, Rp;
    /* derived once: the rhs multiplies instead of dividing */
    double inv_l0, inv_C0, inv_Rs, inv_Rp, share /* Rp/(Rs+Rp) */, relax_M /* E_M/eta_M */;
    /* the amplifier (0: off): output time constant 1/(2 pi bandwidth) (s), slew-rate limit
     * (V/s), current limit (A); the laws of the current step (AMP_*, VA_*) */
    double amp_tau, amp_slew, amp_imax;
    int i_law, v_law;
    /* amplifier.c's scratch in a control period: the charge's and the output's last transient
     * (start time in the period, s; time constant, s; size, V) */
    double charge_t0, charge_tau, charge_dv, output_t0, output_dv;
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
    int owned;                         /* the buffer is this scratch's (ds_work_init) */
} ds_work;

int ds_work_init(ds_work *w, const ds_model *m);
int64_t ds_work_size(const ds_model *m);
void ds_work_attach(ds_work *w, const ds_model *m, double *buf);
void ds_work_free(ds_work *w);

/* physics.c */
int ds_rhs(const ds_model *m, const double *x, const double *u, double *dx, ds_work *w,
           int quasi_static);
int ds_stiff_rates(const ds_model *m, const double *x, double *L, ds_work *w, int enabled);
int ds_outputs(const ds_model *m, const double *x, const double *u, double *out, ds_work *w);
void ds_kinematics(const ds_model *m, const double *x, ds_work *w, int with_bending);
void ds_stretches(const ds_model *m, const double *x, ds_work *w, double *lam);
void ds_shift_charge(const ds_model *m, double *x, const double *u, double sign, ds_work *w);
void ds_book_input_jump(const ds_model *m, double *x, const double *u_old, const double *u_new,
                        ds_work *w);
int64_t ds_n_outputs(const ds_model *m);

/* exact.c: an exact cell's y (m), qd' H_y qd (m/s^2) and bending energy beyond EI int w''^2
 * (J) from its coordinates q and rates qd, with dy/dq into J and, unless F is NULL, that
 * energy's gradient subtracted from F (all of the cell's nr terms); its y alone; B1T, B2T
 * from the rows B1, B2 (once per model). */
typedef struct {
    double y, h, bending;
} ds_exact_sums;
ds_exact_sums ds_exact_cell(const ds_model *m, const ds_cell *cell, const double *q,
                            const double *qd, double *J, double *F);
double ds_exact_shortening(const ds_model *m, const ds_cell *cell, const double *q);
void ds_transpose_nodes(const ds_model *m, const double *rows, double *out);
int ds_mass_inverse(const ds_model *m, double *out);   /* physics.c, once per model */

/* One DET's supply under its amplifier's laws: the current through Rs (A), the amplifier's
 * terminal voltage v_out and the voltage behind Rs v_src (V; v_a, or the command without an
 * output lag) with its rate (V/s). */
typedef struct {
    double current, v_out, v_src, v_src_rate;
} ds_amp_supply;

/* amplifier.c: the laws at (x, u) into each DET's i_law, v_law; one DET's supply (v_p: its
 * voltage); the voltage DET i's charge relaxes towards (times Rp/(Rs+Rp)) in its current law,
 * against which the quasi-static coordinates count charge and energy: v_src while linear, 0 at
 * the limit (where the charge does not relax). */
void ds_amp_laws(const ds_model *m, const double *x, const double *u, ds_work *w);
ds_amp_supply ds_amp_supply_of(const ds_model *m, int64_t i, const double *x, const double *u,
                               double vp);
double ds_amp_relax(const ds_model *m, int64_t i, const double *x, const double *u);

#endif
