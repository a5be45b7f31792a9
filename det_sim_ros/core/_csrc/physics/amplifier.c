/*
 * The amplifier's laws (see amplifier.h): which law each DET follows at a state, and the
 * supply under it.
 */
#include <math.h>

#include "physics/amplifier.h"

#define SLEW_MARGIN 1e-9    /* relative: a gap within S tau_a (1 + SLEW_MARGIN) is followed */

static int output_law(const ds_det *d, double u, double va)
{
    if (!ds_amp_has_output_state(d))
        return VA_HOLD;
    const double gap = u - va;
    if (d->amp_slew > 0.0 && fabs(gap) > d->amp_slew * d->amp_tau * (1.0 + SLEW_MARGIN))
        return gap > 0.0 ? VA_SLEW_UP : VA_SLEW_DOWN;
    return d->amp_tau > 0.0 ? VA_FOLLOW : VA_HOLD;
}

static double output_rate(const ds_det *d, int v_law, double u, double va)
{
    switch (v_law) {
    case VA_FOLLOW: return (u - va) / d->amp_tau;
    case VA_SLEW_UP: return d->amp_slew;
    case VA_SLEW_DOWN: return -d->amp_slew;
    default: return 0.0;
    }
}

void ds_amp_laws(const ds_model *m, const double *x, const double *u, ds_work *w)
{
    for (int64_t i = 0; i < m->n_cells; i++) {
        const ds_det *d = &m->det[i];
        w->v_law[i] = m->amp_state ? output_law(d, u[i], x[m->i_va + i]) : VA_HOLD;
        w->i_law[i] = AMP_LINEAR;
        if (d->amp_imax > 0.0) {
            const double s = ds_amp_linear_share(m, i, x, u, w);
            if (fabs(s) >= 1.0 - DS_AMP_LIMIT_MARGIN)
                w->i_law[i] = s > 0.0 ? AMP_LIMIT_POS : AMP_LIMIT_NEG;
        }
    }
}

ds_amp_supply ds_amp_supply_of(const ds_model *m, int64_t i, const double *x, const double *u,
                               const ds_work *w, double vp)
{
    const ds_det *d = &m->det[i];
    const int i_law = w->i_law[i];
    ds_amp_supply s;
    s.v_src = ds_amp_source_voltage(m, d, i, x, u);
    s.v_src_rate = m->amp_state && ds_amp_has_output_state(d)
                   ? output_rate(d, w->v_law[i], u[i], s.v_src) : 0.0;
    if (i_law != AMP_LINEAR) {
        s.current = i_law == AMP_LIMIT_POS ? d->amp_imax : -d->amp_imax;
        s.v_out = vp + d->Rs * s.current;
    } else {
        s.current = (s.v_src - vp) * d->inv_Rs;
        s.v_out = s.v_src;
    }
    return s;
}

double ds_amp_relax(const ds_model *m, int64_t i, const double *x, const double *u,
                    const ds_work *w)
{
    const ds_det *d = &m->det[i];
    return w->i_law[i] == AMP_LINEAR ? ds_amp_source_voltage(m, d, i, x, u) : 0.0;
}
