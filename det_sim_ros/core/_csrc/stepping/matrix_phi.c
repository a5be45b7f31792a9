/*
 * The phi functions of a small dense matrix, phi_k(Z) = sum_m Z^m / (m + k)!, k = 0..k_max, by
 * scaling and squaring: a diagonal balancing by powers of two (exact), Z / 2^s with a 1-norm of
 * at most 1/2, a Taylor polynomial of phi_{k_max} there (Horner), the downward recurrence
 * phi_{k-1} = Z phi_k + I / (k-1)!, then s doublings
 *     phi_k(2Z) = 2^-k (phi_0(Z) phi_k(Z) + sum_{j=1..k} phi_j(Z) / (k-j)!).
 * The doubling before the last gives phi_k(Z / 2) as well (an exponential Runge-Kutta table's
 * c = 1/2 arguments). det_sim_ros/physics/matrix_phi.py is the same in numpy; the tests hold
 * this code to it and to the series.
 */
#include <math.h>
#include <string.h>

#include "stepping/matrix_phi.h"

#define TAYLOR_DEGREE 13   /* |Z| <= 1/2: the first term left out is < 1e-15 of the sum */
#define PHI_NORM 0.5

/* C = A B for n x n row-major matrices (C distinct from A and B). */
static void matmul(const double *restrict A, const double *restrict B, double *restrict C,
                   int64_t n)
{
    for (int64_t i = 0; i < n; i++) {
        double *c = C + i * n;
        for (int64_t j = 0; j < n; j++)
            c[j] = 0.0;
        for (int64_t k = 0; k < n; k++) {
            const double a = A[i * n + k];
            const double *b = B + k * n;
            for (int64_t j = 0; j < n; j++)
                c[j] += a * b[j];
        }
    }
}

/* Powers of two d (d[i] = 2^e_i) that make row and column i of D^-1 Z D of similar 1-norm
 * (the balancing of LAPACK's gebal, without permutations): exact in binary arithmetic. */
static void balance(const double *Z, int64_t n, double *d)
{
    for (int64_t i = 0; i < n; i++)
        d[i] = 1.0;
    for (int sweep = 0, changed = 1; changed && sweep < 40; sweep++) {
        changed = 0;
        for (int64_t i = 0; i < n; i++) {
            double col = 0.0, row = 0.0;
            for (int64_t j = 0; j < n; j++) {
                if (j == i)
                    continue;
                col += fabs(Z[j * n + i]) * d[i] / d[j];   /* of D^-1 Z D */
                row += fabs(Z[i * n + j]) * d[j] / d[i];
            }
            if (col == 0.0 || row == 0.0)
                continue;
            double f = 1.0;
            const double s = col + row;
            while (col < 0.5 * row) {
                col *= 2.0;
                row *= 0.5;
                f *= 2.0;
            }
            while (col >= 2.0 * row) {
                col *= 0.5;
                row *= 2.0;
                f *= 0.5;
            }
            if (col + row < 0.95 * s) {
                d[i] *= f;
                changed = 1;
            }
        }
    }
}

/* Taylor polynomials of phi_0..phi_kmax of Y (|Y|_1 <= 1/2) into P ((kmax + 1) blocks). */
static void taylor_phis(const double *Y, int64_t n, int64_t kmax, double *P, double *tmp)
{
    const int64_t nn = n * n;
    double inv_fact[TAYLOR_DEGREE + 8];
    inv_fact[0] = 1.0;
    for (int64_t m = 1; m < TAYLOR_DEGREE + 8; m++)
        inv_fact[m] = inv_fact[m - 1] / (double)m;
    double *top = P + kmax * nn;
    memset(top, 0, (size_t)nn * sizeof(double));
    for (int64_t i = 0; i < n; i++)
        top[i * n + i] = inv_fact[TAYLOR_DEGREE + kmax];
    for (int64_t m = TAYLOR_DEGREE - 1; m >= 0; m--) {
        matmul(Y, top, tmp, n);
        for (int64_t i = 0; i < n; i++)
            tmp[i * n + i] += inv_fact[m + kmax];
        memcpy(top, tmp, (size_t)nn * sizeof(double));
    }
    for (int64_t k = kmax; k > 0; k--) {
        double *lower = P + (k - 1) * nn;
        matmul(Y, P + k * nn, lower, n);
        for (int64_t i = 0; i < n; i++)
            lower[i * n + i] += inv_fact[k - 1];
    }
}

/* phi_k(2Y) from phi_k(Y), k = 0..kmax, in place (tmp: (kmax + 1) n^2 doubles). */
static void double_phis(double *P, int64_t n, int64_t kmax, double *tmp)
{
    const int64_t nn = n * n;
    for (int64_t k = 0; k <= kmax; k++) {
        double *out = tmp + k * nn;
        matmul(P, P + k * nn, out, n);
        double fact = 1.0;   /* (k - j)! for j = k, k-1, ..., 1 */
        for (int64_t j = k; j >= 1; j--) {
            const double *Pj = P + j * nn;
            const double w = 1.0 / fact;
            for (int64_t e = 0; e < nn; e++)
                out[e] += w * Pj[e];
            fact *= (double)(k - j + 1);
        }
        const double scale = ldexp(1.0, (int)-k);
        for (int64_t e = 0; e < nn; e++)
            out[e] *= scale;
    }
    memcpy(P, tmp, (size_t)((kmax + 1) * nn) * sizeof(double));
}

int64_t ds_matrix_phi_work(int64_t n, int64_t kmax)
{
    return 2 * (kmax + 1) * n * n + n * n + n;
}

/* The doubling count s of scale Z (1-norm of the balanced scale Z at most PHI_NORM 2^s, at
 * least one doubling). Computed with the scale inside each term: for scale 2^j the terms, their
 * sums and so s move by exactly j (powers of two), which keeps chains comparable. */
static int doublings(const double *Z, double scale, int64_t n, const double *d)
{
    double norm = 0.0;
    for (int64_t j = 0; j < n; j++) {
        double col = 0.0;
        for (int64_t i = 0; i < n; i++)
            col += fabs(scale * Z[i * n + j] * d[j] / d[i]);
        if (col > norm)
            norm = col;
    }
    int s = 1;   /* at least one doubling: phi_k(Z / 2) comes from the chain */
    while (s < 1000 && norm > PHI_NORM * ldexp(1.0, s))
        s++;
    return s;
}

/* phi(Z) = D phi(D^-1 Z D) D^-1: the balanced blocks P into out. */
static void unbalance(const double *P, const double *d, int64_t n, int64_t kmax, double *out)
{
    const int64_t nn = n * n;
    for (int64_t b = 0; b <= kmax; b++)
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                out[b * nn + i * n + j] = P[b * nn + i * n + j] * (d[i] / d[j]);
}

/* The Taylor base of the chain of scale Z with s doublings, balanced, into P. */
static void chain_base(const double *Z, double scale, int64_t n, int64_t kmax, int s,
                       const double *d, double *P, double *tmp, double *Y)
{
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++)
            Y[i * n + j] = ldexp(scale * Z[i * n + j] * d[j] / d[i], -s);
    taylor_phis(Y, n, kmax, P, tmp);
}

/*
 * full[k] = phi_k(scale Z), half[k] = phi_k(scale Z / 2) for k = 0..kmax (blocks of n x n,
 * row-major); work: ds_matrix_phi_work(n, kmax) doubles.
 */
void ds_matrix_phis(const double *Z, double scale, int64_t n, int64_t kmax, double *full,
                    double *half, double *work)
{
    const int64_t nn = n * n, nb = (kmax + 1) * nn;
    double *P = work, *tmp = P + nb, *Y = tmp + nb, *d = Y + nn;
    balance(Z, n, d);
    const int s = doublings(Z, scale, n, d);
    chain_base(Z, scale, n, kmax, s, d, P, tmp, Y);
    for (int i = 0; i < s; i++) {
        if (i == s - 1)
            unbalance(P, d, n, kmax, half);
        double_phis(P, n, kmax, tmp);
    }
    unbalance(P, d, n, kmax, full);
}

int64_t ds_phi_chain_doubles(int64_t n, int64_t kmax)
{
    return n + (DS_CHAIN_LEVELS + 1) * (kmax + 1) * n * n;
}

void ds_phi_chain_init(ds_phi_chain *c, int64_t n, double *mem)
{
    c->d = mem;
    c->levels = mem + n;
    ds_phi_chains_clear(c, 1);
}

void ds_phi_chains_clear(ds_phi_chain *chains, int n_chains)
{
    for (int k = 0; k < n_chains; k++) {
        chains[k].base = 0.0;
        chains[k].top = -1;
        chains[k].used = 0;
    }
}

/*
 * As ds_matrix_phis, through chains of the same Z (cleared when Z changes): the chain of
 * scale Z is its Taylor base Y = scale Z / 2^s and the doublings Y 2^i, i = 1..s, kept
 * balanced per level. A scale 2^j times another's has the same base, bit for bit (every
 * operation before the base scales exactly by powers of two), so its phis are a kept level
 * (j < 0) or a few more doublings of the top one (j > 0): the same numbers as computed anew,
 * at no or 4 n^3 (kmax + 1) operations per level instead of the whole chain. The step counts
 * of linearized methods (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, ...) fall in a few such families.
 * Returns 1 when a chain was built anew, 0 when a kept one served.
 */
int ds_matrix_phis_chained(const double *Z, double scale, int64_t n, int64_t kmax,
                           ds_phi_chain *chains, int n_chains, double *full, double *half,
                           double *work)
{
    const int64_t nn = n * n, nb = (kmax + 1) * nn;
    double *tmp = work + nb, *Y = tmp + nb;
    ds_phi_chain *c = NULL;
    int s = 0, built = 0;
    for (int k = 0; k < n_chains && !c; k++) {
        ds_phi_chain *ck = &chains[k];
        if (ck->top < 0)
            continue;
        s = doublings(Z, scale, n, ck->d);
        if (ldexp(scale, -s) == ck->base)
            c = ck;
    }
    if (!c) {   /* the least recently used chain, built anew */
        c = &chains[0];
        for (int k = 1; k < n_chains; k++)
            if (chains[k].used < c->used)
                c = &chains[k];
        balance(Z, n, c->d);
        s = doublings(Z, scale, n, c->d);
        if (s > DS_CHAIN_LEVELS) {   /* beyond the kept levels: computed alone */
            ds_matrix_phis(Z, scale, n, kmax, full, half, work);
            return 1;
        }
        chain_base(Z, scale, n, kmax, s, c->d, c->levels, tmp, Y);
        c->base = ldexp(scale, -s);
        c->top = 0;
        built = 1;
    }
    if (s > DS_CHAIN_LEVELS) {
        ds_matrix_phis(Z, scale, n, kmax, full, half, work);
        return 1;
    }
    for (; c->top < s; c->top++) {
        double *next = c->levels + (c->top + 1) * nb;
        memcpy(next, c->levels + c->top * nb, (size_t)nb * sizeof(double));
        double_phis(next, n, kmax, tmp);
    }
    int64_t newest = 0;
    for (int k = 0; k < n_chains; k++)
        if (chains[k].used > newest)
            newest = chains[k].used;
    c->used = newest + 1;
    unbalance(c->levels + (s - 1) * nb, c->d, n, kmax, half);
    unbalance(c->levels + s * nb, c->d, n, kmax, full);
    return built;
}
