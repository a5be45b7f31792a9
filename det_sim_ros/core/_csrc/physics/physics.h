/*
 * The model's equations (physics.c): the right-hand side, the stiff rates the exponential
 * stages take exactly, the kinematics, and the charge's bookkeeping at an input jump. Its
 * scratch is work.h's, its mass solves mass.h's.
 */
#ifndef DETSIM_PHYSICS_PHYSICS_H
#define DETSIM_PHYSICS_PHYSICS_H

#include "physics/mass.h"
#include "physics/model.h"
#include "physics/work.h"

int ds_rhs(const ds_model *m, const double *x, const double *u, double *dx, ds_work *w,
           int quasi_static);
int ds_stiff_rates(const ds_model *m, const double *x, double *L, ds_work *w, int enabled);
void ds_kinematics(const ds_model *m, const double *x, ds_work *w, int with_bending);
void ds_stretches(const ds_model *m, const double *x, ds_work *w, double *lam);
void ds_shift_charge(const ds_model *m, double *x, const double *u, double sign, ds_work *w);
void ds_book_input_jump(const ds_model *m, double *x, const double *u_old, const double *u_new,
                        ds_work *w);

#endif
