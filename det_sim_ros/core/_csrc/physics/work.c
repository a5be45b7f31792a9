/*
 * The right-hand side's scratch (ds_work): one buffer laid out per model (work.h).
 */
#include <stdlib.h>
#include <string.h>

#include "physics/work.h"

int64_t ds_work_size(const ds_model *m)
{
    const int64_t nc = m->n_cells, nq = m->n_q;
    const int64_t laws = (2 * nc * (int64_t)sizeof(int) + (int64_t)sizeof(double) - 1)
                         / (int64_t)sizeof(double);   /* i_law, v_law */
    return 2 * nc + 2 * nq + nq * m->mass_block + 2 * nc + m->n_state + 1 + laws;
}

/* Lay the scratch out in ``buf`` (ds_work_size doubles, owned by the caller). */
void ds_work_attach(ds_work *w, const ds_model *m, double *buf)
{
    const int64_t nc = m->n_cells, nq = m->n_q;
    memset(w, 0, sizeof(*w));
    w->y = buf;
    w->h = w->y + nc;
    w->J = w->h + nc;
    w->F = w->J + nq;
    w->Mt = w->F + nq;
    w->Us4 = w->Mt + nq * m->mass_block;
    w->ydot = w->Us4 + nc;
    w->dx = w->ydot + nc;
    w->i_law = (int *)(w->dx + m->n_state + 1);
    w->v_law = w->i_law + nc;
}

int ds_work_init(ds_work *w, const ds_model *m)
{
    double *buf = calloc((size_t)ds_work_size(m), sizeof(double));
    if (!buf)
        return -1;
    ds_work_attach(w, m, buf);
    w->owned = 1;
    return 0;
}

void ds_work_free(ds_work *w)
{
    if (w->owned)
        free(w->y);
    w->y = NULL;
    w->owned = 0;
}
