/*
 * The kinds of stepper (kind.h): the table's stages, the same with a dense linear part over
 * the beams' q, qdot, and the variable-order BDF stepper.
 */
#include "stepping/kind.h"

#include <stdlib.h>
#include <string.h>

#include "stepping/bdf.h"
#include "stepping/linear_part.h"
#include "stepping/period.h"

static int nothing_to_init(const ds_stepper *st, ds_group *g)
{
    (void)st;
    (void)g;
    return 0;
}

static void nothing_to_do(ds_group *g)
{
    (void)g;
}

static const char *steps_any(const ds_model *m, const ds_kind_options *o)
{
    (void)m;
    (void)o;
    return NULL;
}

/* ---------------------------------------------------------------- the table's stages */

static const ds_kind stages = {
    .name = "stages", .options = "", .refuse = steps_any, .group_init = nothing_to_init,
    .group_reset = nothing_to_do, .group_free = nothing_to_do, .period = ds_stages_period,
};

/* ---------------------------------------------------------------- with a dense linear part */

static int linear_init(const ds_stepper *st, ds_group *g)
{
    g->lin = malloc(sizeof(ds_linear));
    if (!g->lin)
        return -1;
    const int rc = ds_linear_init(g->lin, &st->method, g->m);
    if (rc < 0) {
        free(g->lin);
        g->lin = NULL;
    }
    return rc;
}

static void linear_reset(ds_group *g)
{
    ds_linear_reset(g->lin);
}

static void linear_free(ds_group *g)
{
    if (g->lin)
        ds_linear_free(g->lin);
    free(g->lin);
    g->lin = NULL;
}

static const ds_kind linearized = {
    .name = "linearized", .options = "refresh refresh_input", .refuse = steps_any,
    .group_init = linear_init, .group_reset = linear_reset, .group_free = linear_free,
    .period = ds_stages_period,
};

/* ---------------------------------------------------------------- BDF */

static const char *bdf_refuses(const ds_model *m, const ds_kind_options *o)
{
    if (m->n_groups != 1 || m->amp)
        return "the BDF stepper steps one coupled group without an amplifier";
    if (!(o->tolerance > 0.0) || !o->weights)
        return "the BDF stepper needs the options tolerance > 0 and weights";
    return NULL;
}

static int bdf_init(const ds_stepper *st, ds_group *g)
{
    g->bdf = malloc(sizeof(ds_bdf));
    /* the power monitor's integrals come last: bookkeeping, out of the iteration */
    const int64_t n_core = g->m->power ? g->m->i_power : g->m->n_state;
    if (!g->bdf || ds_bdf_init(g->bdf, g->m->n_state, n_core, st->options.weights,
                               st->options.tolerance) < 0) {
        free(g->bdf);
        g->bdf = NULL;
        return -1;
    }
    return 0;
}

static void bdf_reset(ds_group *g)
{
    ds_bdf_reset(g->bdf);
}

static void bdf_free(ds_group *g)
{
    if (g->bdf)
        ds_bdf_free(g->bdf);
    free(g->bdf);
    g->bdf = NULL;
}

/* its own steps and step control; a jump of the input needs no special steps */
static int bdf_period(const ds_stepper *st, ds_group *g, double *x, const double *u_old,
                      const double *u)
{
    (void)u_old;
    return ds_bdf_period(st, g, x, u);
}

static const ds_kind bdf = {
    .name = "bdf", .options = "tolerance weights", .refuse = bdf_refuses,
    .group_init = bdf_init, .group_reset = bdf_reset, .group_free = bdf_free,
    .period = bdf_period, .whole_periods = 1,
};

/* ---------------------------------------------------------------- the table of kinds */

const ds_kind_number ds_kind_numbers[] = {
    {"refresh", offsetof(ds_kind_options, refresh)},
    {"refresh_input", offsetof(ds_kind_options, refresh_input)},
    {"tolerance", offsetof(ds_kind_options, tolerance)},
    {NULL, 0},
};

const ds_kind *const ds_kinds[] = {&stages, &linearized, &bdf, NULL};

const ds_kind *ds_kind_named(const char *name)
{
    for (int i = 0; ds_kinds[i]; i++)
        if (strcmp(ds_kinds[i]->name, name) == 0)
            return ds_kinds[i];
    return NULL;
}

int ds_kind_reads(const ds_kind *kind, const char *option)
{
    const size_t n = strlen(option);
    for (const char *p = kind->options; n && (p = strstr(p, option)); p += n)
        if ((p == kind->options || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0'))
            return 1;
    return 0;
}
