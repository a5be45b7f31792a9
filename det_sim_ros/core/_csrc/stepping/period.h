/*
 * One control period of one group (period.c): the charge transient after an input jump,
 * the step-count controller; batch.c runs it for each group.
 */
#ifndef DETSIM_STEPPING_PERIOD_H
#define DETSIM_STEPPING_PERIOD_H

#include "stepping/group.h"

/* One control period of one group by the method table's stages (the kinds 'stages' and
 * 'linearized', kind.c); on failure x holds its start. */
int ds_stages_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                     const double *u);

#endif
