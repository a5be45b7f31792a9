/*
 * The right-hand side's scratch (ds_work, model.h): its size for a model, its layout in a
 * caller's buffer or one of its own (work.c).
 */
#ifndef DETSIM_PHYSICS_WORK_H
#define DETSIM_PHYSICS_WORK_H

#include "physics/model.h"

int ds_work_init(ds_work *w, const ds_model *m);
int64_t ds_work_size(const ds_model *m);
void ds_work_attach(ds_work *w, const ds_model *m, double *buf);
void ds_work_free(ds_work *w);

#endif
