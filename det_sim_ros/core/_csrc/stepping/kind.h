/*
 * How a coupled group steps: one entry per kind of method (kind.c), the one place the kinds
 * are told apart. An entry says what the kind keeps per group (its init, reset and free),
 * which of the options it reads, which models it cannot step, and its control period.
 *
 * A new coefficient table is data (a row of det_sim_ros/sim/integrators.py's METHODS, decoded
 * by method.c) and needs no entry; a new kind of stepper is one file plus one entry here, its
 * options in ds_kind_options (group.h) with their names in ds_kind_numbers (kind.c), and its
 * per-group state a field of ds_group (group.h, as lin and bdf).
 */
#ifndef DETSIM_STEPPING_KIND_H
#define DETSIM_STEPPING_KIND_H

#include <stddef.h>

#include "stepping/group.h"

typedef struct ds_kind {
    const char *name;       /* as det_sim_ros.sim.integrators names the kind */
    const char *options;    /* the ds_kind_options fields it reads, space separated */
    /* NULL when the kind can step the model with these options, else why not (one line) */
    const char *(*refuse)(const ds_model *m, const ds_kind_options *o);
    /* the group's own state: 0, -1 without memory, -2 when the method table cannot carry it */
    int (*group_init)(const ds_stepper *st, ds_group *g);
    void (*group_reset)(ds_group *g);
    void (*group_free)(ds_group *g);
    /* one control period of the group from x (in place) with u held, u_old the last period's
     * input; a status, and on failure x holds its start (period.h, bdf.h) */
    int (*period)(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                  const double *u);
    int whole_periods;      /* steps only whole control periods (advance() refuses it) */
} ds_kind;

/* The number-valued fields of ds_kind_options by name (the binding reads them so; the one
 * array option, weights, is a buffer). NULL-terminated. */
typedef struct {
    const char *name;
    size_t offset;          /* of its double in ds_kind_options */
} ds_kind_number;
extern const ds_kind_number ds_kind_numbers[];

/* Every kind, NULL-terminated. */
extern const ds_kind *const ds_kinds[];

/* The kind of that name; NULL: none. */
const ds_kind *ds_kind_named(const char *name);

/* Whether the kind reads the option of that name. */
int ds_kind_reads(const ds_kind *kind, const char *option);

#endif
