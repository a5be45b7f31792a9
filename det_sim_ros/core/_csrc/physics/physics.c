/*
 * The DET-beam physics: right-hand side, stiff rates, outputs (see det_sim_ros/physics/model.py
 * for the derivation from energies and virtual works, and det_sim_ros/physics/reference.py for
 * the same equations in readable numpy, which the tests hold this code to).
 *
 * State layout: q (n_q), qdot (n_q), eps_E (n_cells, if creep), q_p (n_cells, if RC source),
 * then the supplied and dissipated energy (2, if the power monitor is on).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "physics/physics.h"
#include "physics/amplifier.h"
#include "physics/exact.h"

/* y = c2 q^2 + kappa c4 q^4 of a one-term cell (paper/consistent kinematics). */
static inline double one_term_shortening(const ds_cell *cell, double q)
{
    const double c2 = cell->c2, c4 = cell->kappa * cell->c4, q2 = q * q;
    return c2 * q2 + c4 * q2 * q2;
}

/*
 * End shortening y_c, its gradient J = dy/dq, qd' H_y qd per cell and, with ``with_bending``,
 * the bending energy beyond EI int w''^2 (Us4), from q = x[:n_q], qd = x[n_q:2 n_q].
 *
 * paper/consistent: y = int w'^2/2 + kappa w'^4/8; exact (exact.c): sin(theta) = w',
 * y = int 1 - cos theta, bending beyond EI int w''^2 is EI int w''^2 w'^2 / (1 - w'^2)
 * (curvature^2 = w''^2/(1 - w'^2)); |w'| >= 1 gives NaN, which the callers report as a slope
 * domain error.
 */
static void kinematics_cells(const ds_model *m, const double *x, ds_work *w, int with_bending,
                             int exact_too)
{
    const int64_t nq = m->n_q, R = m->r_max;
    const double *qd = x + nq;
    for (int64_t c = 0; c < m->n_cells; c++) {
        const ds_cell *cell = &m->cell[c];
        const int64_t o = cell->q0, r = cell->nr;
        if (cell->kinematics == KIN_EXACT) {
            if (!exact_too)
                continue;
            const ds_exact_sums s = ds_exact_cell(m, cell, x + o, qd + o, w->J + o, NULL);
            w->y[c] = s.y;
            w->h[c] = s.h;
            if (with_bending)
                w->Us4[c] = s.bending;
            continue;
        }
        if (r == 1) {   /* one term: closed-form polynomials in q, no quadrature to run */
            const double c2 = cell->c2, c4 = cell->kappa * cell->c4;
            const double qc = x[o], q2 = qc * qc;
            w->y[c] = one_term_shortening(cell, qc);
            w->J[o] = 2.0 * c2 * qc + 4.0 * c4 * q2 * qc;
            w->h[c] = (2.0 * c2 + 12.0 * c4 * q2) * qd[o] * qd[o];
            if (with_bending)
                w->Us4[c] = cell->e4 * q2 * q2;
            continue;
        }
        double yc = 0.0, hc = 0.0, u4 = 0.0;
        for (int64_t j = 0; j < r; j++)
            w->J[o + j] = 0.0;
        for (int64_t g = cell->g0; g < cell->g1; g++) {
            const double *b1 = m->B1 + g * R, *b2 = m->B2 + g * R;
            double wp = 0.0, wd = 0.0;
            for (int64_t j = 0; j < r; j++) {
                wp += b1[j] * x[o + j];
                wd += b1[j] * qd[o + j];
            }
            const double wg = m->W[g], wp2 = wp * wp;
            yc += wg * (0.5 * wp2 + 0.125 * cell->kappa * wp2 * wp2);
            hc += wg * (1.0 + 1.5 * cell->kappa * wp2) * wd * wd;
            const double gy = wg * (wp + 0.5 * cell->kappa * wp2 * wp);
            for (int64_t j = 0; j < r; j++)
                w->J[o + j] += gy * b1[j];
            if (with_bending) {
                double wpp = 0.0;
                for (int64_t j = 0; j < r; j++)
                    wpp += b2[j] * x[o + j];
                u4 += cell->EI * wg * wpp * wpp * wp2;
            }
        }
        w->y[c] = yc;
        w->h[c] = hc;
        if (with_bending)
            w->Us4[c] = u4;
    }
}

void ds_kinematics(const ds_model *m, const double *x, ds_work *w, int with_bending)
{
    kinematics_cells(m, x, w, with_bending, 1);
}

/* The end shortenings y alone (into w->y), as ds_kinematics computes them: what the stiff
 * rates, the stretches and the charge shift need, once or twice per step. */
static void end_shortenings(const ds_model *m, const double *x, ds_work *w)
{
    const int64_t R = m->r_max;
    for (int64_t c = 0; c < m->n_cells; c++) {
        const ds_cell *cell = &m->cell[c];
        const int64_t o = cell->q0, r = cell->nr;
        if (cell->kinematics == KIN_EXACT) {
            w->y[c] = ds_exact_shortening(m, cell, x + o);
            continue;
        }
        if (r == 1) {
            w->y[c] = one_term_shortening(cell, x[o]);
            continue;
        }
        double yc = 0.0;
        for (int64_t g = cell->g0; g < cell->g1; g++) {
            const double *b1 = m->B1 + g * R;
            double wp = 0.0;
            for (int64_t j = 0; j < r; j++)
                wp += b1[j] * x[o + j];
            const double wg = m->W[g], wp2 = wp * wp;
            yc += wg * (0.5 * wp2 + 0.125 * cell->kappa * wp2 * wp2);
        }
        w->y[c] = yc;
    }
}

/* F -= gradient of the bending energy beyond EI int w''^2: EI int w''^2 g, g = w'^2 (eq 51) or,
 * exact, g = w'^2 / (1 - w'^2); an exact cell's kinematics (into w) come with it, from the
 * same pass over its quadrature nodes (exact.c). */
static void quartic_force(const ds_model *m, const double *x, double *F, ds_work *w)
{
    const int64_t R = m->r_max;
    for (int64_t c = 0; c < m->n_cells; c++) {
        const ds_cell *cell = &m->cell[c];
        const int64_t o = cell->q0, r = cell->nr;
        if (cell->kinematics == KIN_EXACT) {
            const ds_exact_sums s = ds_exact_cell(m, cell, x + o, x + m->n_q + o, w->J + o,
                                                  F + o);
            w->y[c] = s.y;
            w->h[c] = s.h;
            continue;
        }
        if (r == 1) {
            F[o] -= 4.0 * cell->e4 * x[o] * x[o] * x[o];
            continue;
        }
        const double EI2 = 2.0 * cell->EI;
        for (int64_t g = cell->g0; g < cell->g1; g++) {
            const double *b1 = m->B1 + g * R, *b2 = m->B2 + g * R;
            double wp = 0.0, wpp = 0.0;
            for (int64_t j = 0; j < r; j++) {
                wp += b1[j] * x[o + j];
                wpp += b2[j] * x[o + j];
            }
            const double s1 = EI2 * m->W[g] * wpp * wpp * wp;
            const double s2 = EI2 * m->W[g] * wpp * wp * wp;
            for (int64_t j = 0; j < r; j++)
                F[o + j] -= s1 * b1[j] + s2 * b2[j];
        }
    }
}

/* What the DETs supply and dissipate, summed over the cells in order (W). */
typedef struct {
    double p_in, p_leak_in, p_diss;     /* p_leak_in: the rate of W_in - v q_p (quasi-static) */
} det_power;

/* A DET's electrical state in the rhs: stretch, dy/dt (m/s), charge (C) and voltage (V), and
 * the voltage its charge relaxes towards in the quasi-static coordinates (ds_amp_relax). */
typedef struct {
    double lam, jqd, qp, vp, v_relax;
} det_state;

/* The RC circuit fed by the command v: the current through Rs (returned), dq_p/dt (into *dqp)
 * and Rs i^2 (added to *p_diss). */
static inline __attribute__((always_inline)) double
rc_circuit(const ds_det *d, double v, const det_state *s, int quasi_static, double *dqp,
           double *p_diss)
{
    const double i_de = (v - s->vp) * d->inv_Rs;
    *dqp = v * d->inv_Rs - (d->inv_Rs + d->inv_Rp) * s->vp;
    if (quasi_static)   /* minus d(C v_inf)/dt, dC/dt = 2 C0 lam dlam/dt */
        *dqp += 2.0 * d->C0 * s->lam * s->jqd * d->inv_l0 * v * d->share;
    *p_diss += (v - s->vp) * i_de;
    return i_de;
}

/* The supply circuit of DET i under its amplifier's laws (amplifier.c): dq_p/dt, dv_a/dt into
 * dx; the supplied power v_out i, the rate of W_in - v_relax q_p and Rs i^2 added to *pw. */
static void amplified_circuit(const ds_model *m, int64_t i, const double *x, const double *u,
                              const ds_work *w, const det_state *s, int quasi_static,
                              double *dx, det_power *pw)
{
    const ds_det *d = &m->det[i];
    const ds_amp_supply a = ds_amp_supply_of(m, i, x, u, w, s->vp);
    const double relax_rate = w->i_law[i] == AMP_LINEAR ? a.v_src_rate : 0.0;
    dx[m->i_qp + i] = a.current - s->vp * d->inv_Rp;
    if (m->amp_state)
        dx[m->i_va + i] = a.v_src_rate;
    if (quasi_static)   /* minus d(C v_relax Rp/(Rs+Rp))/dt */
        dx[m->i_qp + i] += (2.0 * d->C0 * s->lam * s->jqd * d->inv_l0 * s->v_relax
                            - d->C0 * s->lam * s->lam * relax_rate) * d->share;
    pw->p_in += a.v_out * a.current;
    pw->p_leak_in += (a.v_out - s->v_relax) * a.current + s->v_relax * s->vp * d->inv_Rp
                     - relax_rate * s->qp;
    pw->p_diss += (a.v_out - s->vp) * a.current;
}

/* The beam of a one-term cell: its end shortening y, dy/dq J and the force F (N) and mass Mt
 * (kg) of its coordinate without the DET, with their damping power p_diss (W). */
typedef struct {
    double y, J, F, Mt, p_diss;
} one_term_beam;

static inline __attribute__((always_inline)) one_term_beam
one_term_mechanics(const ds_model *m, double q, double qd)
{
    const ds_cell *cell = &m->cell[0];
    const double q2 = q * q;
    const double c2 = cell->c2, c4 = cell->kappa * cell->c4;
    one_term_beam b;
    b.y = one_term_shortening(cell, q);
    b.J = 2.0 * c2 * q + 4.0 * c4 * q2 * q;
    const double hq = (2.0 * c2 + 12.0 * c4 * q2) * qd * qd;
    const double dq = m->D[0] * qd;
    b.F = -(m->K[0] * q) - dq;
    b.p_diss = qd * dq;
    b.F -= 4.0 * cell->e4 * q * q * q;
    b.Mt = m->Mb[0];
    for (int64_t e = 0; e < m->n_mi; e++) {   /* at most one entry: MI[0, 0] */
        b.F -= m->mi_val[e] * b.J * hq;
        b.Mt += m->mi_val[e] * b.J * b.J;
    }
    return b;
}

/*
 * ds_rhs for a model of one one-term cell (a scene at the paper's level, and each copy of such
 * an array when it steps as its own group): the same operations in the same order as the
 * general code below (so the same bits), with everything in registers instead of the scratch
 * arrays, where the general path loops over cells, terms and mass entries.
 */
static int rhs_one_term(const ds_model *m, const double *x, const double *u, double *dx,
                        ds_work *w, int quasi_static)
{
    const ds_cell *cell = &m->cell[0];
    const ds_det *d = &m->det[0];
    const double qd = x[1];
    const one_term_beam beam = one_term_mechanics(m, x[0], qd);
    const double y = beam.y, J = beam.J;
    double F = beam.F, p_diss = beam.p_diss;
    w->y[0] = y;
    const double lam = (cell->length - y) * d->inv_l0;
    if (!(lam > 0.0))
        return lam == lam ? DS_BAD_STRETCH : DS_BAD_SLOPE;
    const double inv_lam = 1.0 / lam, inv_lam2 = inv_lam * inv_lam;
    const double v = u[0];
    const double v_relax = m->amp ? ds_amp_relax(m, 0, x, u, w) : v;
    double vp, bracket, qp = 0.0;
    if (m->rc_source) {
        qp = x[m->i_qp];
        if (quasi_static)
            qp += d->C0 * lam * lam * v_relax * d->share;
        vp = qp * d->inv_C0 * inv_lam2;
        bracket = d->VY / 3.0 * (lam - inv_lam2 * inv_lam) - qp * vp * inv_lam;
    } else {
        vp = v;
        bracket = d->VY / 3.0 * (lam - inv_lam2 * inv_lam) - d->C0 * lam * vp * vp;
    }
    const double jqd = 0.0 + J * qd;
    const double lzd = jqd * d->inv_l0 * inv_lam2;
    const double eps = m->creep ? x[m->i_eps] : 0.0;
    const double visc = d->volume * (d->E_M * eps + d->eta_v * lzd);
    const double coef = (bracket - visc * inv_lam2) * d->inv_l0;
    F += coef * J;
    if (m->creep)
        dx[m->i_eps] = lzd - d->relax_M * eps;
    const det_state s = {lam, jqd, qp, vp, v_relax};
    det_power pw = {0.0, v * vp * d->inv_Rp, 0.0};
    if (m->amp) {
        pw.p_leak_in = 0.0;
        amplified_circuit(m, 0, x, u, w, &s, quasi_static, dx, &pw);
        p_diss += pw.p_diss;
    } else {
        const double i_de = m->rc_source
            ? rc_circuit(d, v, &s, quasi_static, &dx[m->i_qp], &p_diss)
            : -2.0 * d->C0 * lam * jqd * d->inv_l0 * vp + vp * d->inv_Rp;
        pw.p_in += v * i_de;
    }
    const double p_in = pw.p_in;
    p_diss += vp * vp * d->inv_Rp + d->volume * d->eta_v * lzd * lzd;
    if (m->creep)
        p_diss += d->volume * d->E_M * d->relax_M * eps * eps;
    dx[1] = F / beam.Mt;
    dx[0] = qd;
    w->p_in = p_in;
    w->p_diss = p_diss;
    if (m->power) {   /* quasi-static: the rate of W_in - v q_p (see ds_shift_charge) */
        dx[m->i_power] = quasi_static && m->rc_source ? pw.p_leak_in : p_in;
        dx[m->i_power + 1] = p_diss;
    }
    return DS_OK;
}

/* The cells' blocks of K, D and Mb: F = -K q - D qd and the mass blocks Mt (not for a cell
 * solved alone, whose solve reads Mb^-1); then the bending
 * force beyond EI int w''^2 and the interface mass's terms (w->J, w->h from ds_kinematics).
 * Returns the damping power qd' D qd. */
static double structure_forces(const ds_model *m, const double *x, ds_work *w)
{
    const int64_t nq = m->n_q, nc = m->n_cells, R = m->r_max, ld = m->mass_block;
    const double *qd = x + nq;
    double *F = w->F, *J = w->J, *Mt = w->Mt;
    double p_diss = 0.0;
    for (int64_t c = 0; c < nc; c++) {   /* cell blocks of K, D and Mb */
        const ds_cell *cell = &m->cell[c];
        const int64_t o = cell->q0, r = cell->nr, col = cell->mass_col;
        const int64_t size = m->group_q[cell->group + 1] - m->group_q[cell->group];
        for (int64_t i = o; i < o + r; i++) {
            double s = 0.0, dq = 0.0;
            for (int64_t k = 0; k < r; k++) {
                s += m->K[i * R + k] * x[o + k];
                dq += m->D[i * R + k] * qd[o + k];
            }
            F[i] = -s - dq;
            p_diss += qd[i] * dq;
        }
        if (ds_solved_alone(m, cell))
            continue;
        for (int64_t i = o; i < o + r; i++) {
            for (int64_t k = 0; k < size; k++)
                Mt[i * ld + k] = 0.0;
            for (int64_t k = 0; k < r; k++)
                Mt[i * ld + col + k] = m->Mb[i * R + k];
        }
    }
    quartic_force(m, x, F, w);
    /* Interface mass on the end shortenings: T_I = 1/2 ydot' MI ydot with ydot_c = J_c . qdot */
    for (int64_t e = 0; e < m->n_mi; e++) {
        const int64_t c = m->mi_row[e], c2 = m->mi_col[e];
        const double mi = m->mi_val[e];
        const int64_t go = m->group_q[m->cell[c].group];
        const ds_cell *a = &m->cell[c], *b = &m->cell[c2];
        const int assembled = !ds_solved_alone(m, a);
        for (int64_t j = a->q0; j < a->q0 + a->nr; j++) {
            F[j] -= mi * J[j] * w->h[c2];
            for (int64_t k = b->q0; assembled && k < b->q0 + b->nr; k++)
                Mt[j * ld + k - go] += mi * J[j] * J[k];
        }
    }
    return p_diss;
}

/* The DET of cell i: its force on the cell's coordinates (into w->F), the rates of its creep
 * strain and charge (into dx), its powers (added to *pw). Returns a status code. */
static int det_cell(const ds_model *m, int64_t i, const double *x, const double *u, double *dx,
                    ds_work *w, int quasi_static, det_power *pw)
{
    const double *qd = x + m->n_q, *J = w->J;
    const ds_det *d = &m->det[i];
    const ds_cell *cell = &m->cell[i];
    const double lam = (cell->length - w->y[i]) * d->inv_l0;
    if (!(lam > 0.0))   /* NaN: exact kinematics past |w'| = 1 (states are finite) */
        return lam == lam ? DS_BAD_STRETCH : DS_BAD_SLOPE;
    const double inv_lam = 1.0 / lam, inv_lam2 = inv_lam * inv_lam;
    double vp, bracket, qp = 0.0;
    /* the voltage the charge relaxes towards (times Rp/(Rs+Rp)); see ds_amp_relax */
    const double v_relax = m->amp ? ds_amp_relax(m, i, x, u, w) : u[i];
    /* dU_DE/dlambda without the sign of dlambda/dq = -J/l0 (eq 53, corrected eq 71) */
    if (m->rc_source) {
        qp = x[m->i_qp + i];
        if (quasi_static)
            qp += d->C0 * lam * lam * v_relax * d->share;
        vp = qp * d->inv_C0 * inv_lam2;
        bracket = d->VY / 3.0 * (lam - inv_lam2 * inv_lam) - qp * vp * inv_lam;
    } else {
        vp = u[i];
        bracket = d->VY / 3.0 * (lam - inv_lam2 * inv_lam) - d->C0 * lam * vp * vp;
    }
    double jqd = 0.0;
    for (int64_t j = cell->q0; j < cell->q0 + cell->nr; j++)
        jqd += J[j] * qd[j];
    const double lzd = jqd * d->inv_l0 * inv_lam2;   /* d(lambda_z)/dt, lambda_z = 1/lambda */
    const double eps = m->creep ? x[m->i_eps + i] : 0.0;
    /* Maxwell spring + Kelvin-Voigt stress (eq 67) */
    const double visc = d->volume * (d->E_M * eps + d->eta_v * lzd);
    const double coef = (bracket - visc * inv_lam2) * d->inv_l0;
    for (int64_t j = cell->q0; j < cell->q0 + cell->nr; j++)
        w->F[j] += coef * J[j];
    if (m->creep)
        dx[m->i_eps + i] = lzd - d->relax_M * eps;
    const det_state s = {lam, jqd, qp, vp, v_relax};
    if (m->amp) {   /* the amplifier's laws of this step (amplifier.c) */
        amplified_circuit(m, i, x, u, w, &s, quasi_static, dx, pw);
    } else {
        double i_de;
        if (m->rc_source)
            i_de = rc_circuit(d, u[i], &s, quasi_static, &dx[m->i_qp + i], &pw->p_diss);
        else   /* q_p = C0 lam^2 v: i = dq_p/dt + v/Rp with dlambda/dt = -J.qdot / l0 */
            i_de = -2.0 * d->C0 * lam * jqd * d->inv_l0 * vp + vp * d->inv_Rp;
        pw->p_in += u[i] * i_de;
        pw->p_leak_in += u[i] * vp * d->inv_Rp;
    }
    pw->p_diss += vp * vp * d->inv_Rp + d->volume * d->eta_v * lzd * lzd;
    if (m->creep)
        pw->p_diss += d->volume * d->E_M * d->relax_M * eps * eps;
    return DS_OK;
}

/* ds_rhs for any model: cells of any number of Ritz terms, coupled groups, the exact kinematics
 * (kept out of line: its register saves and set-up would otherwise run on every one-term call). */
static int __attribute__((noinline))
rhs_general(const ds_model *m, const double *x, const double *u, double *dx, ds_work *w,
            int quasi_static)
{
    const int64_t nq = m->n_q, nc = m->n_cells;
    const double *qd = x + nq;
    kinematics_cells(m, x, w, 0, 0);   /* exact cells: in structure_forces' bending pass */
    det_power pw = {0.0, 0.0, 0.0};
    pw.p_diss = structure_forces(m, x, w);
    int status = DS_OK;
    for (int64_t i = 0; i < nc && status == DS_OK; i++)
        status = det_cell(m, i, x, u, dx, w, quasi_static, &pw);
    ds_mass_solve(m, w, dx);
    for (int64_t i = 0; i < nq; i++)
        dx[i] = qd[i];
    w->p_in = pw.p_in;
    w->p_diss = pw.p_diss;
    if (m->power) {   /* quasi-static: the rate of W_in - v q_p (see ds_shift_charge) */
        dx[m->i_power] = quasi_static && m->rc_source ? pw.p_leak_in : pw.p_in;
        dx[m->i_power + 1] = pw.p_diss;
    }
    return status;
}

/*
 * dx = f(x, u); returns a status code. Finiteness of x is checked once per step by the callers.
 *
 * With ``quasi_static`` the charge slots hold z = q_p - C(q) v_inf (v_inf = v Rp/(Rs+Rp), the
 * charge the circuit relaxes to for frozen q) and receive dz/dt (see stepping/period.c), and the
 * supplied-energy slot receives the rate of W_in - v q_p, v v_p / Rp (see ds_shift_charge).
 * w->p_in, w->p_diss receive the supplied and dissipated power (W) either way.
 */
int ds_rhs(const ds_model *m, const double *x, const double *u, double *dx, ds_work *w,
           int quasi_static)
{
    const int status = m->one_term ? rhs_one_term(m, x, u, dx, w, quasi_static)
                                   : rhs_general(m, x, u, dx, w, quasi_static);
    if (w->nan_after > 0 && --w->nan_after == 0) {   /* a planted fault (tests only) */
        dx[m->n_q] = NAN;   /* an acceleration: every stepper reads it */
        w->nan_after = w->nan_lasting;
    }
    return status;
}

/* Diagonal linear part for exponential steppers: dq_p/dt = -q_p/(C Rs||Rp) + ...; all zero
 * unless ``enabled`` (an exponential method on an RC scene). Returns a status code. */
int ds_stiff_rates(const ds_model *m, const double *x, double *L, ds_work *w, int enabled)
{
    for (int64_t k = 0; k < m->n_state; k++)
        L[k] = 0.0;
    if (!enabled || !m->rc_source)
        return DS_OK;
    if (m->one_term)   /* once per step: only y is needed, not the whole kinematics */
        w->y[0] = one_term_shortening(&m->cell[0], x[0]);
    else
        end_shortenings(m, x, w);
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        const double lam = (m->cell[i].length - w->y[i]) / d->l0;
        if (!(lam > 0.0))
            return lam == lam ? DS_BAD_STRETCH : DS_BAD_SLOPE;
        /* at the amplifier's current limit the charge relaxes through Rp only */
        const double g = w->i_law[i] == AMP_LINEAR ? d->inv_Rs + d->inv_Rp : d->inv_Rp;
        L[m->i_qp + i] = -g * d->inv_C0 / (lam * lam);
        if (m->amp_state)   /* v_a: exact in each law (a first-order lag, a ramp, held) */
            L[m->i_va + i] = w->v_law[i] == VA_FOLLOW ? -1.0 / d->amp_tau : 0.0;
    }
    return DS_OK;
}

/* DET stretches lambda_c = (l_c - y_c(q)) / l0_c. */
void ds_stretches(const ds_model *m, const double *x, ds_work *w, double *lam)
{
    end_shortenings(m, x, w);
    for (int64_t i = 0; i < m->n_cells; i++)
        lam[i] = (m->cell[i].length - w->y[i]) / m->det[i].l0;
}

/*
 * q_p += sign * C(q) v_inf: to (sign -1) and from (+1) the quasi-static charge coordinates z.
 * With the power monitor, also W_in -= v q_p on the way in and += on the way out: in between,
 * the stages integrate xi = W_in - v q_p, whose rate v v_p / Rp (v held) is as smooth as the
 * mechanics, instead of the supplied power v i, whose charging current follows every input
 * jump on the charge time scale Rs C. The supplied energy v dq_p then comes exactly from the
 * charge the exponential stages integrate: a quadrature of v i would miss part of each jump
 * under a controller's new voltage every period, and the power balance would flag a run whose
 * outputs are right (test_supplied_energy_is_exact_under_a_new_voltage_every_period).
 */
void ds_shift_charge(const ds_model *m, double *x, const double *u, double sign, ds_work *w)
{
    end_shortenings(m, x, w);
    double work_in = 0.0, work_out = 0.0;   /* v q_p before the shift, after it */
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        const double lam = (m->cell[i].length - w->y[i]) / d->l0;
        /* with an amplifier: against what its current law relaxes the charge to */
        const double v = m->amp ? ds_amp_relax(m, i, x, u, w) : u[i];
        work_in += v * x[m->i_qp + i];
        x[m->i_qp + i] += sign * d->C0 * lam * lam * v * d->share;
        work_out += v * x[m->i_qp + i];
    }
    if (m->power)
        x[m->i_power] += sign < 0.0 ? -work_in : work_out;
}

/*
 * Ideal source with the power monitor: book an instantaneous recharge (in place). A voltage
 * step moves the charge C dv at once: the source supplies v_new C dv and the vanishing series
 * resistance dissipates C dv^2 / 2 (the R -> 0 limit of the RC charging loss).
 */
void ds_book_input_jump(const ds_model *m, double *x, const double *u_old, const double *u_new,
                        ds_work *w)
{
    if (m->rc_source || !m->power)
        return;
    int jump = 0;
    for (int64_t i = 0; i < m->n_cells; i++)
        jump |= u_new[i] != u_old[i];
    if (!jump)
        return;
    ds_kinematics(m, x, w, 0);
    for (int64_t i = 0; i < m->n_cells; i++) {
        const double lam = (m->cell[i].length - w->y[i]) / m->det[i].l0;
        const double cap = m->det[i].C0 * lam * lam, dv = u_new[i] - u_old[i];
        x[m->i_power] += u_new[i] * cap * dv;
        x[m->i_power + 1] += 0.5 * cap * dv * dv;
    }
}
