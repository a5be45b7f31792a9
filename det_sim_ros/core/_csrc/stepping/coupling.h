/*
 * The charge's exact coupling to an amplifier output that follows its command (coupling.c):
 * stages.c calls these where g->cpl is set.
 */
#ifndef DETSIM_STEPPING_COUPLING_H
#define DETSIM_STEPPING_COUPLING_H

#include "stepping/group.h"

int64_t ds_coupling_size(const ds_method *me);
int ds_coupling_fits(const ds_method *me);
void ds_coupling_weights(const ds_method *me, ds_group *g, double h);
void ds_coupling_row(const ds_method *me, const ds_group *g, int64_t row, const double *x,
                     const double *N, double h, double *X);
void ds_coupling_remainder(const ds_method *me, const ds_group *g, const double *X, double *N);

#endif
