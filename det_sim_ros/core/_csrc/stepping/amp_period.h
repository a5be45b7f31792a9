/*
 * One control period of one group of an amplified model (amp_period.c): steps of at most h
 * (n_sub of them without switches), split where a law of the amplifier (physics/amplifier.h)
 * switches; the DETs' transients in g->transient. On failure x holds the period's start.
 */
#ifndef DETSIM_STEPPING_AMP_PERIOD_H
#define DETSIM_STEPPING_AMP_PERIOD_H

#include "stepping/group.h"

int ds_amp_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                  const double *u, double h, int64_t n_sub);

#endif
