/*
 * The whole model's control periods, the groups one by one or over threads, and offline
 * runs of many periods with their outputs (batch.c).
 */
#ifndef DETSIM_STEPPING_BATCH_H
#define DETSIM_STEPPING_BATCH_H

#include "stepping/group.h"

int ds_period(ds_stepper *st, double *x, const double *u_old, const double *u);
/* n periods from x, period k holding U[k]: X[0] receives x, X[k + 1] and Y[k + 1] the state
 * and outputs after period k; *done the periods completed. On failure x is X[*done], the
 * state the last good period ended with. */
int ds_run(ds_stepper *st, ds_work *ow, double *x, const double *u_held, const double *u_last,
           const double *U, int64_t n, double *X, double *Y, int64_t *done);

#endif
