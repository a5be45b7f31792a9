/*
 * The exact kinematics' quadrature (exact.c): an exact cell's y (m), qd' H_y qd (m/s^2) and
 * bending energy beyond EI int w''^2 (J) from its coordinates q and rates qd, with dy/dq into
 * J and, unless F is NULL, that energy's gradient subtracted from F (all of the cell's nr
 * terms); its y alone; B1T, B2T from the rows B1, B2 (once per model).
 */
#ifndef DETSIM_PHYSICS_EXACT_H
#define DETSIM_PHYSICS_EXACT_H

#include "physics/model.h"

typedef struct {
    double y, h, bending;
} ds_exact_sums;

ds_exact_sums ds_exact_cell(const ds_model *m, const ds_cell *cell, const double *q,
                            const double *qd, double *J, double *F);
double ds_exact_shortening(const ds_model *m, const ds_cell *cell, const double *q);
void ds_transpose_nodes(const ds_model *m, const double *rows, double *out);

#endif
