/*
 * The named outputs of a state (det_sim_ros.physics.model.output_names): per cell the
 * reference deflection and rate, end shortening, stretch, charge, voltage, current, capacitance
 * and creep strain, then the structure outputs, the energy H and the powers (physics.c holds
 * the right-hand side they share).
 */
#include <math.h>

#include "physics/outputs.h"
#include "physics/amplifier.h"
#include "physics/physics.h"

int64_t ds_n_outputs(const ds_model *m)
{
    return m->n_cells * DS_CELL_OUTPUTS + m->n_structure + 3;
}

/* The beams' kinetic and elastic energy (J), with the interface mass's kinetic energy; the
 * end-shortening rates dy/dt into w->ydot (w->J, w->Us4 from ds_kinematics with bending). */
static double mechanical_energy(const ds_model *m, const double *x, ds_work *w)
{
    const int64_t R = m->r_max;
    const double *qd = x + m->n_q;
    double energy = 0.0;
    for (int64_t c = 0; c < m->n_cells; c++) {
        const int64_t o = m->cell[c].q0, r = m->cell[c].nr;
        w->ydot[c] = 0.0;
        for (int64_t i = o; i < o + r; i++)
            for (int64_t k = 0; k < r; k++)
                energy += 0.5 * qd[i] * m->Mb[i * R + k] * qd[o + k]
                          + 0.5 * x[i] * m->K[i * R + k] * x[o + k];
        energy += w->Us4[c];
        for (int64_t j = o; j < o + r; j++)
            w->ydot[c] += w->J[j] * qd[j];
    }
    for (int64_t e = 0; e < m->n_mi; e++)
        energy += 0.5 * m->mi_val[e] * w->ydot[m->mi_row[e]] * w->ydot[m->mi_col[e]];
    return energy;
}

/* The structure outputs: rows of P applied to the end shortenings y. */
static void structure_outputs(const ds_model *m, const double *y, double *out)
{
    const int64_t nc = m->n_cells;
    for (int64_t r = 0; r < m->n_structure; r++) {
        double value = 0.0;
        for (int64_t c = 0; c < nc; c++)
            value += m->P[r * nc + c] * y[c];
        out[r] = value;
    }
}

/*
 * The named outputs (det_sim_ros.physics.model.output_names); returns a status code.
 * Per cell: q_ref, qdot_ref, y, lambda, q_p, v_p, i_DE, C, eps_E; then the structure outputs
 * (rows of P applied to y), H, P_in, P_diss.
 */
int ds_outputs(const ds_model *m, const double *x, const double *u, double *out, ds_work *w)
{
    const int64_t nq = m->n_q, nc = m->n_cells;
    const double *qd = x + nq;
    int status = DS_OK;
    for (int64_t k = 0; k < m->n_state; k++)
        if (!isfinite(x[k]))
            status = DS_NON_FINITE;
    if (m->amp && status == DS_OK) {
        ds_stretches(m, x, w, w->Us4);   /* w->y */
        ds_amp_laws(m, x, u, w);
    }
    const int rhs_status = ds_rhs(m, x, u, w->dx, w, 0);
    if (status == DS_OK)
        status = rhs_status;
    const double p_in = w->p_in, p_diss = w->p_diss;
    ds_kinematics(m, x, w, 1);
    double energy = mechanical_energy(m, x, w);
    for (int64_t c = 0; c < nc; c++) {
        const ds_det *d = &m->det[c];
        const double lam = (m->cell[c].length - w->y[c]) / d->l0, lam2 = lam * lam;
        const double cap = d->C0 * lam2;
        double qp, vp, i_de;
        if (m->rc_source) {
            qp = x[m->i_qp + c];
            vp = qp / cap;
            i_de = m->amp ? ds_amp_supply_of(m, c, x, u, w, vp).current : (u[c] - vp) / d->Rs;
        } else {
            vp = u[c];
            qp = cap * vp;
            i_de = 2.0 * d->C0 * lam * (-w->ydot[c] / d->l0) * vp + vp / d->Rp;
        }
        const double eps = m->creep ? x[m->i_eps + c] : 0.0;
        energy += d->VY / 6.0 * (lam2 + 1.0 / lam2 - 2.0) + 0.5 * qp * qp / cap;
        energy += 0.5 * d->volume * d->E_M * eps * eps;
        double qr = 0.0, qdr = 0.0;
        for (int64_t j = m->cell[c].q0; j < m->cell[c].q0 + m->cell[c].nr; j++) {
            qr += m->ref[j] * x[j];
            qdr += m->ref[j] * qd[j];
        }
        double *o = out + c * DS_CELL_OUTPUTS;
        o[0] = qr;
        o[1] = qdr;
        o[2] = w->y[c];
        o[3] = lam;
        o[4] = qp;
        o[5] = vp;
        o[6] = i_de;
        o[7] = cap;
        o[8] = eps;
    }
    int64_t k = nc * DS_CELL_OUTPUTS;
    structure_outputs(m, w->y, out + k);
    k += m->n_structure;
    out[k] = energy;
    out[k + 1] = p_in;
    out[k + 2] = p_diss;
    const int64_t n_out = ds_n_outputs(m);
    for (k = 0; k < n_out; k++)
        if (!isfinite(out[k]) && status == DS_OK)
            status = DS_NON_FINITE;
    return status;
}
