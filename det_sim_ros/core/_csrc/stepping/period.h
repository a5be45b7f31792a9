/*
 * One control period of one group (period.c): the charge transient after an input jump,
 * the step-count controller; batch.c runs it for each group.
 */
#ifndef DETSIM_STEPPING_PERIOD_H
#define DETSIM_STEPPING_PERIOD_H

#include "stepping/group.h"

int ds_period_core(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                   const double *u);

#endif
