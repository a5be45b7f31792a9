/*
 * The mass solves (mass.c): qdot' from the generalized forces, per coupled group, and each
 * cell's inverted mass block.
 */
#ifndef DETSIM_PHYSICS_MASS_H
#define DETSIM_PHYSICS_MASS_H

#include "physics/model.h"

/* Whether a cell of several terms is alone in its coupled group: its mass is solved by
 * ds_mass_solve from Mb^-1 (Sherman-Morrison), so the assembled block Mt is not needed. */
static inline int ds_solved_alone(const ds_model *m, const ds_cell *cell)
{
    return cell->nr > 1 && m->group_q[cell->group + 1] - m->group_q[cell->group] == cell->nr;
}

int ds_mass_inverse(const ds_model *m, double *out);   /* once per model */
/* dqdot/dt into dx[n_q:2 n_q] from w->F (and w->Mt, w->J). */
void ds_mass_solve(const ds_model *m, ds_work *w, double *dx);

#endif
