/*
 * The floor for the compiled kernel's cost per internal step: classical RK4 with
 * fixed steps on the same one-term DET-beam model (paper kinematics, creep, RC source, power
 * monitor), written as plain scalar C with every constant in a local: what a hand-written
 * simulator of exactly this scene would cost. bench/kernel_floor.py compiles it with the same
 * flags as the package, checks that it follows the kernel's trajectory and times both.
 *
 * State: q, qd, eps_E, q_p, W_in, W_diss.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdint.h>
#include <time.h>

typedef struct {
    double m_tot;            /* Mb + m J^2 is state dependent: kept as Mb and m */
    double Mb, K, D, m;      /* beam mass, stiffness, damping (1x1), interface mass */
    double c2, e4;           /* y = c2 q^2; bending beyond EI int w''^2 = e4 q^4 */
    double length, l0, VY, C0, V, E_M, eta_M, eta_v, Rs, Rp;
    double v;                /* held voltage */
} floor_params;

static void rhs(const floor_params *p, const double *x, double *dx)
{
    const double q = x[0], qd = x[1], eps = x[2], qp = x[3];
    const double y = p->c2 * q * q, J = 2.0 * p->c2 * q, h = 2.0 * p->c2 * qd * qd;
    const double lam = (p->length - y) / p->l0, lam2 = lam * lam;
    const double vp = qp / (p->C0 * lam2);
    const double bracket = p->VY / 3.0 * (lam - 1.0 / (lam2 * lam)) - qp * vp / lam;
    const double lzd = J * qd / (p->l0 * lam2);
    const double visc = p->V * (p->E_M * eps + p->eta_v * lzd);
    double F = -p->K * q - p->D * qd - 4.0 * p->e4 * q * q * q - p->m * J * h
               + (bracket - visc / lam2) / p->l0 * J;
    dx[0] = qd;
    dx[1] = F / (p->Mb + p->m * J * J);
    dx[2] = lzd - p->E_M / p->eta_M * eps;
    const double i_de = (p->v - vp) / p->Rs;
    dx[3] = p->v / p->Rs - (1.0 / p->Rs + 1.0 / p->Rp) * vp;
    dx[4] = p->v * i_de;
    dx[5] = qd * p->D * qd + (p->v - vp) * i_de + vp * vp / p->Rp + p->V * p->eta_v * lzd * lzd
            + p->V * p->E_M * p->E_M / p->eta_M * eps * eps;
}

/* n_steps RK4 steps of h from x (in place); returns the CPU seconds they took. */
double rk4_floor(const floor_params *p, double *x, double h, int64_t n_steps)
{
    struct timespec t0, t1;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t0);
    double k1[6], k2[6], k3[6], k4[6], s[6];
    for (int64_t n = 0; n < n_steps; n++) {
        rhs(p, x, k1);
        for (int i = 0; i < 6; i++) s[i] = x[i] + 0.5 * h * k1[i];
        rhs(p, s, k2);
        for (int i = 0; i < 6; i++) s[i] = x[i] + 0.5 * h * k2[i];
        rhs(p, s, k3);
        for (int i = 0; i < 6; i++) s[i] = x[i] + h * k3[i];
        rhs(p, s, k4);
        for (int i = 0; i < 6; i++) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t1);
    return (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
}
