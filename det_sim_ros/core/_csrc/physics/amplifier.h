/*
 * The high-voltage amplifier's laws in the supply circuit (amplifier.c; the model in
 * det_sim_ros/scenes/amplifier.py, the numpy reference in det_sim_ros/physics/reference.py):
 *
 *   output voltage  dv_a/dt = clip((u - v_a) / tau_a, -S, S)   (tau_a = 1/(2 pi bandwidth);
 *                   without a bandwidth v_a ramps at +-S to u; without either v_a = u)
 *   supply current  i = clip((v_a - v_p) / Rs, -I, I),  dq_p/dt = i - v_p / Rp
 *
 * Both are piecewise smooth: each DET follows one law per step (ds_work.v_law: following,
 * slewing up or down, held; ds_work.i_law: linear or at the limit), set at the step's start
 * (ds_amp_laws). The limit law starts at |i| = I (1 - DS_AMP_LIMIT_MARGIN) and holds while the
 * linear law's current i_lin is beyond that on its own side, so the current never exceeds I.
 * Within a law everything is smooth, and each law's own linear part goes to the exponential
 * stages (physics.c, ds_stiff_rates): at the limit the charge relaxes through Rp only, and
 * v_a's rate is -1/tau_a when following, 0 otherwise. The supplied power is v_out i at the
 * amplifier's terminal, v_out = v_a (linear) or v_p + Rs i (at the limit): what the amplifier
 * delivers into Rs and the DET. Where the steps end so that a law holds over each is the
 * stepper's (stepping/amp_period.h).
 */
#ifndef DETSIM_PHYSICS_AMPLIFIER_H
#define DETSIM_PHYSICS_AMPLIFIER_H

#include <math.h>

#include "physics/model.h"

/* A DET's current law: linear (through Rs) or at the limit; its output voltage's law. */
enum { AMP_LINEAR = 0, AMP_LIMIT_POS = 1, AMP_LIMIT_NEG = 2 };
enum { VA_FOLLOW = 0, VA_SLEW_UP = 1, VA_SLEW_DOWN = 2, VA_HOLD = 3 };

#define DS_AMP_LIMIT_MARGIN 1e-6   /* relative: the limit law starts at |i| = I (1 - margin) */

/* One DET's supply under its amplifier's laws: the current through Rs (A), the amplifier's
 * terminal voltage v_out and the voltage behind Rs v_src (V; v_a, or the command without an
 * output lag) with its rate (V/s). */
typedef struct {
    double current, v_out, v_src, v_src_rate;
} ds_amp_supply;

/* The laws at (x, u) into w->i_law, w->v_law (w->y from ds_stretches at x, which the
 * caller runs first); one DET's supply (v_p: its voltage); the
 * voltage DET i's charge relaxes towards (times Rp/(Rs+Rp)) in its current law, against which
 * the quasi-static coordinates count charge and energy: v_src while linear, 0 at the limit
 * (where the charge does not relax). */
void ds_amp_laws(const ds_model *m, const double *x, const double *u, ds_work *w);
ds_amp_supply ds_amp_supply_of(const ds_model *m, int64_t i, const double *x, const double *u,
                               const ds_work *w, double vp);
double ds_amp_relax(const ds_model *m, int64_t i, const double *x, const double *u,
                    const ds_work *w);

/* Whether the amplifier's output v_a is a state (a bandwidth or a slew-rate limit). */
static inline int ds_amp_has_output_state(const ds_det *d)
{
    return d->amp_tau > 0.0 || d->amp_slew > 0.0;
}

/* The voltage behind Rs: the amplifier's output v_a, or the command when it has no lag. */
static inline double ds_amp_source_voltage(const ds_model *m, const ds_det *d, int64_t i,
                                           const double *x, const double *u)
{
    return m->amp_state && ds_amp_has_output_state(d) ? x[m->i_va + i] : u[i];
}

/* v_p of cell i from x (w->y from ds_stretches), and its capacitance *cap. */
static inline double ds_amp_det_voltage(const ds_model *m, int64_t i, const double *x,
                                        const ds_work *w, double *cap)
{
    const ds_det *d = &m->det[i];
    const double lam = (m->cell[i].length - w->y[i]) * d->inv_l0;
    *cap = d->C0 * lam * lam;
    return x[m->i_qp + i] / *cap;
}

/* The linear law's current over the limit, i_lin / I. */
static inline double ds_amp_linear_share(const ds_model *m, int64_t i, const double *x,
                                         const double *u, const ds_work *w)
{
    const ds_det *d = &m->det[i];
    double cap;
    const double vp = ds_amp_det_voltage(m, i, x, w, &cap);
    return (ds_amp_source_voltage(m, d, i, x, u) - vp) * d->inv_Rs / d->amp_imax;
}

/* How far past the switch out of DET i's current law the state is (< 0: the law holds; the
 * limit law holds while i_lin is beyond I (1 - DS_AMP_LIMIT_MARGIN) on its own side). */
static inline double ds_amp_past_switch(const ds_model *m, int64_t i, const double *x,
                                        const double *u, const ds_work *w)
{
    const double s = ds_amp_linear_share(m, i, x, u, w), edge = 1.0 - DS_AMP_LIMIT_MARGIN;
    switch (w->i_law[i]) {
    case AMP_LIMIT_POS: return edge - s;
    case AMP_LIMIT_NEG: return s + edge;
    default: return fabs(s) - edge;
    }
}

#endif
