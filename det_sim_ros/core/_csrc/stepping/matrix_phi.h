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

#endif
