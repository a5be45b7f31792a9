/*
 * A method's coefficient table decoded for the stages (method.c; the tables are
 * det_sim_ros/sim/integrators.py's) and the phi functions its weights are made of.
 */
#ifndef DETSIM_STEPPING_METHOD_H
#define DETSIM_STEPPING_METHOD_H

#include <stdint.h>

/* A method table decoded for the core (see det_sim_ros/sim/integrators.py; method.c). */
typedef struct {
    int64_t n_stages, n_terms, n_args, k_max, n_embedded, exponential;
    double *c;                          /* stage nodes (n_stages) */
    int64_t *term_stage, *term_phi;     /* per term: stage j of N_j, phi index (-1: constant) */
    double *term_weight;
    int64_t *term_arg;                  /* index of the term's phi argument in args */
    double *args;                       /* distinct phi arguments c_arg */
    int64_t *row_start;                 /* terms of stage row i: row_start[i] .. [i+1] */
    int64_t *ec_arg;                    /* exp(c_i z) = phi_0 of args[ec_arg[i]] (-1: none) */
    double *coef0;                      /* term weights at L = 0 */
    int64_t *merged_start, *merged_stage; /* the L = 0 table, equal (row, stage) merged */
    int64_t n_exp_terms, *exp_term;     /* the terms with a phi weight (term_phi >= 0) */
    int64_t *exp_phi_at;                /* their phi_k(c_arg z) in a step's phis */
    double *merged_weight;
    double *embedded;                   /* e_0..e_s of the error estimate (n_embedded) */
} ds_method;

int ds_method_init(ds_method *me, const double *c, int64_t n_stages, const double *terms,
                   int64_t n_terms, const double *embedded, int64_t n_embedded);
void ds_method_free(ds_method *me);

/* out[k] = phi_k(z) for k = 0..n-1: the functions an exponential method's weights are made of
 * (method.c). */
void ds_phi_all(double z, double *out, int64_t n);

#endif
