/*
 * A model's stepper set up (stepper.c): one ds_group per coupled group, a model view with
 * local indices when the model has several, each group's scratch in one arena.
 */
#ifndef DETSIM_STEPPING_STEPPER_H
#define DETSIM_STEPPING_STEPPER_H

#include "stepping/group.h"

/* st->method must be initialised (ds_method_init) before. */
int ds_stepper_init(ds_stepper *st, const ds_model *m, double dt, double z_tol, double fine,
                    const ds_control *ctl, const double *inv_scale);
void ds_stepper_free(ds_stepper *st);
/* Every group's step-count controller, error estimate and linear part back to the start. */
void ds_reset_control(ds_stepper *st);

#endif
