/*
 * phi_k(scale Z) for k = 0..kmax of a dense n x n matrix Z, and of scale Z / 2, by scaling
 * and squaring (matrix_phi.c): the weights of an exponential table over a dense linear part
 * (linear_part.h). ``work`` holds ds_matrix_phi_work(n, kmax) doubles.
 */
#ifndef DETSIM_STEPPING_MATRIX_PHI_H
#define DETSIM_STEPPING_MATRIX_PHI_H

#include <stdint.h>

int64_t ds_matrix_phi_work(int64_t n, int64_t kmax);
void ds_matrix_phis(const double *Z, double scale, int64_t n, int64_t kmax, double *full,
                    double *half, double *work);

/* Levels a chain keeps: doublings of its base (a chain needing more is computed alone). */
#define DS_CHAIN_LEVELS 24

/* One scaling-and-squaring chain of a matrix (matrix_phi.c: ds_matrix_phis_chained). */
typedef struct {
    double base;        /* scale / 2^s of its Taylor base; its levels are valid to top */
    int64_t top;        /* -1: empty */
    int64_t used;       /* when it last served (least recently used is rebuilt) */
    double *d;          /* the balancing (n), then the levels' blocks */
    double *levels;
} ds_phi_chain;

int64_t ds_phi_chain_doubles(int64_t n, int64_t kmax);
void ds_phi_chain_init(ds_phi_chain *c, int64_t n, double *mem);
void ds_phi_chains_clear(ds_phi_chain *chains, int n_chains);
int ds_matrix_phis_chained(const double *Z, double scale, int64_t n, int64_t kmax,
                           ds_phi_chain *chains, int n_chains, double *full, double *half,
                           double *work);

#endif
