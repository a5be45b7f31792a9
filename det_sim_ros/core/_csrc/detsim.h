/*
 * det_sim_ros compiled kernel: the model as named records, the physics and the stepping core.
 *
 * physics.c  right-hand side, stiff rates, outputs, input-jump bookkeeping (the equations are
 *            derived and documented in det_sim_ros/physics/model.py; det_sim_ros/physics/reference.py is the
 *            same physics in readable numpy, and the tests hold this code to it)
 * stepping.c method tables, the exponential Runge-Kutta core, charge transients, the per-period
 *            step-count controller and the per-group batch stepping
 * frames.c   marker frames of one-coordinate cells (the node's display path, not physics)
 * wire.c     the node's sample messages (CDR) and MCAP message records, written from named
 *            fields (the node's I/O path, not physics)
 * module.c   the Python binding (buffer protocol only: no numpy C API, no ABI coupling)
 *
 * Units: SI throughout (m, kg, s, V, C, A, W, J).
 */
#ifndef DETSIM_H
#define DETSIM_H

#include <stdint.h>
#include <string.h>

/* Status codes (same values as det_sim_ros.core.kernel.OK ...). */
enum { DS_OK = 0, DS_BAD_STRETCH = 1, DS_NON_FINITE = 2, DS_BAD_SLOPE = 3 };

/* Kinematics level of a cell (scene fidelity). */
enum { KIN_PAPER = 0, KIN_CONSISTENT = 1, KIN_EXACT = 2 };

#define DS_CELL_OUTPUTS 9   /* q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E */

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
    double c2, c4, e4;      /* one-term closed forms: 1/2 int S'^2, 1/8 int S'^4, EI int S''^2 S'^2 */
} ds_cell;

/* The DET spanning a cell (eqs 53-57, 66-67) and its supply circuit. */
typedef struct {
    double l0, VY, C0, volume, E_M, eta_M, eta_v, Rs, Rp;
    /* derived once: the rhs multiplies instead of dividing */
    double inv_l0, inv_C0, inv_Rs, inv_Rp, share /* Rp/(Rs+Rp) */, relax_M /* E_M/eta_M */;
} ds_det;

/* A model (or one coupled group of a model: a view with local indices). */
typedef struct {
    int64_t n_q, n_cells, n_state, r_max, n_nodes, n_mi, n_groups, n_structure, mass_block;
    int creep, rc_source, power;
    int one_term;                      /* one cell, one Ritz term, not exact: scalar rhs */
    int64_t i_eps, i_qp, i_power;      /* offsets of eps_E, q_p, (W_in, W_diss) in x */
    ds_cell *cell;                     /* n_cells */
    ds_det *det;                       /* n_cells */
    const double *B1, *B2, *W;         /* S_j'(x_g), S_j''(x_g) (n_nodes x r_max), weights */
    const double *Mb, *K, *D;          /* block rows by cell (n_q x r_max) */
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

/* stepping.c */

/* A method table decoded for the core (see det_sim_ros/sim/integrators.py). */
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
    int64_t s0, s1;                     /* states with a stiff rate: [s0, s1) */
    int64_t q_first, c_first;           /* first coordinate and cell in the whole model */
    int quasi_static;
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
} ds_stepper;

/* st->method must be initialised (ds_method_init) before. */
int ds_stepper_init(ds_stepper *st, const ds_model *m, double dt, double z_tol, double fine,
                    const ds_control *ctl, const double *inv_scale);
void ds_stepper_free(ds_stepper *st);
int ds_advance(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
               int64_t n_steps, double growth);
int ds_period(ds_stepper *st, double *x, const double *u_old, const double *u);
void ds_reset_control(ds_stepper *st);
int ds_run(ds_stepper *st, ds_work *ow, double *x, const double *u_held, const double *u_last,
           const double *U, int64_t n, double *X, double *Y, int64_t *done);

/* Marker frames (frames.c): the stacked polynomial map of one-coordinate cells. */
typedef struct {
    int64_t n_cells, n_values;             /* cells; drawn values per cell */
    const double *maps;                    /* (cells, values, 4): the 4 coefficients of V */
    const double *thickness_times_height;  /* n d0 l0 per cell (m^2) */
    const int64_t *coordinate;             /* each cell's q in the state vector */
    const int64_t *position;               /* byte offset of each value in the frame */
    const int64_t *stamp_position;         /* byte offset of each header stamp (sec, nanosec) */
    int64_t n_stamps;
    int64_t height, thickness;             /* indices in a cell's values */
    double min_thickness, tolerance;       /* m */
    double *values, *last;                 /* scratch: this frame's and the last written */
} ds_frame_map;

int ds_frame_update(ds_frame_map *f, const double *x, unsigned char *frame, int force,
                    int64_t stamp_ns);

/* Little-endian (CDR, MCAP) scalars at ``at``. */
static inline void ds_put_u64(unsigned char *at, uint64_t v)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    v = __builtin_bswap64(v);
#endif
    memcpy(at, &v, 8);
}

static inline void ds_put_u32(unsigned char *at, uint32_t v)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    v = __builtin_bswap32(v);
#endif
    memcpy(at, &v, 4);
}

static inline void ds_put_f64(unsigned char *at, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, 8);
    ds_put_u64(at, bits);
}

/* A ROS header stamp (int32 sec, uint32 nanosec) of ``stamp_ns``, as Python's divmod gives. */
static inline void ds_put_stamp(unsigned char *at, int64_t stamp_ns)
{
    int64_t sec = stamp_ns / 1000000000, nanosec = stamp_ns % 1000000000;
    if (nanosec < 0) {
        sec -= 1;
        nanosec += 1000000000;
    }
    ds_put_u32(at, (uint32_t)(int32_t)sec);
    ds_put_u32(at + 4, (uint32_t)nanosec);
}

/*
 * One sample's output messages (wire.c): every published double is read from the simulator's
 * output vector and written into the messages' CDR template, as contract.SampleEncoder does.
 */
enum { DS_WIRE_COPY = 0, DS_WIRE_FROM = 1, DS_WIRE_SCALED = 2 };   /* v; a - v; a (v - b) */
typedef struct {
    int64_t n_values, n_messages;
    const int64_t *source;      /* each double's index in the output vector */
    const int64_t *op;          /* DS_WIRE_COPY, DS_WIRE_FROM or DS_WIRE_SCALED */
    const double *a, *b;        /* their constants (y0; sign and rest) */
    const int64_t *position;    /* byte offset of each double in the messages' bytes */
    const int64_t *stamp_position;   /* byte offset of each message's header stamp */
} ds_sample_wire;

void ds_wire_encode(const ds_sample_wire *w, const double *out, int64_t stamp_ns,
                    unsigned char *messages);

/* MCAP Message record head: opcode 0x05, record length, channel, sequence, log and publish
 * time (the same); the payload follows it. */
#define DS_RECORD_HEAD 31
void ds_record_head(unsigned char *at, uint16_t channel, uint32_t sequence, uint64_t time_ns,
                    uint64_t payload_size);

#endif
