/*
 * n steps of the exponential Runge-Kutta stages on one group (stages.c).
 */
#ifndef DETSIM_STEPPING_STAGES_H
#define DETSIM_STEPPING_STAGES_H

#include "stepping/group.h"

int ds_advance(const ds_stepper *st, ds_group *g, double *x, const double *u, double h,
               int64_t n_steps, double growth);

#endif
