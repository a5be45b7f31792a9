/*
 * The model's named outputs (outputs.c): DS_CELL_OUTPUTS per cell, the structure's outputs,
 * then the mechanical energy and the supplied and dissipated power.
 */
#ifndef DETSIM_PHYSICS_OUTPUTS_H
#define DETSIM_PHYSICS_OUTPUTS_H

#include "physics/model.h"

int64_t ds_n_outputs(const ds_model *m);
int ds_outputs(const ds_model *m, const double *x, const double *u, double *out, ds_work *w);

#endif
