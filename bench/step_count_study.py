"""
Why the exact model's ringing takes tens of steps per period: one period's error against N.

From a state of the 'step' run (default: simply supported eps_b 0.20, exact n_r 5, the period
after t = 60 ms, while the released beam rings), one control period is stepped with N equal
steps by the kernel's etdrk4_linearized (its Jacobian kept from the period's start, as it runs)
and by EXPRB43, the fourth-order exponential Rosenbrock method of Hochbruck, Ostermann and
Schweitzer (SIAM J. Numer. Anal. 2009) with a new Jacobian every step (numpy + scipy expm), each
against the kernel with 4096 steps. Error: the largest weighted q, qdot error (the error norm's
scale: beam length, length per period). Also the kernel's embedded estimate, and the
etdrk4_linearized error at 8 steps split over the modes of the period's Jacobian (frequency,
weighted size). Run: python bench/step_count_study.py [--case simply_supported 0.20] [--at 60];
``--quick``: 1 and 8 steps against 256 (a smoke run).
"""

import argparse

from det_sim_ros.analysis.scenarios import step_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import scipy.linalg

COUNTS = (1, 2, 4, 8, 16, 32, 64)


def phis(Z, k_max=4):
    """Return phi_0..k_max(Z) from one augmented matrix exponential."""
    n = Z.shape[0]
    M = np.zeros((n * (k_max + 1), n * (k_max + 1)))
    M[:n, :n] = Z
    for k in range(k_max):
        M[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = np.eye(n)
    E = scipy.linalg.expm(M)
    return [E[:n, k * n:(k + 1) * n] for k in range(k_max + 1)]


class Period:
    """One control period of a running simulator, stepped in several ways."""

    def __init__(self, sim: Simulator):
        self.sim, self.kernel = sim, sim.model.kernel
        self.x0, self.u = sim.x.copy(), sim.applied_input.copy()
        self.dt, self.n_q = sim.dt, int(sim.model.arrays.cell_q[-1])
        length, nq = sim.scene.beam_length, self.n_q
        self.weights = np.r_[np.full(nq, 1.0 / length), np.full(nq, self.dt / length)]
        # finite-difference scales: the error norm's on q, qdot, 1e-6 on the other states
        self.scales = np.r_[1.0 / self.weights, np.full(len(self.x0) - 2 * nq, 1e-6)]

    def rhs(self, x):
        """Return f(x) at the held input."""
        dx = np.empty_like(x)
        status = self.kernel.rhs(x, self.u, dx)[0]
        if status != 0:
            raise RuntimeError(f'rhs status {status}')
        return dx

    def jacobian(self, x):
        """Return the full Jacobian by forward differences."""
        f0, J = self.rhs(x), np.empty((len(x), len(x)))
        for j in range(len(x)):
            step = 1e-7 * max(abs(x[j]), self.scales[j])
            xp = x.copy()
            xp[j] += step
            J[:, j] = (self.rhs(xp) - f0) / (xp[j] - x[j])
        return J

    def exprb43(self, x, h):
        """Return one EXPRB43 step from x."""
        J, F = self.jacobian(x), self.rhs(x)

        def g(y):
            return self.rhs(y) - J @ y
        P, Ph = phis(h * J), phis(0.5 * h * J)
        U2 = x + 0.5 * h * Ph[1] @ F
        D2 = g(U2) - g(x)
        U3 = x + h * P[1] @ (F + D2)
        D3 = g(U3) - g(x)
        return x + h * P[1] @ F + h * (16 * P[3] - 48 * P[4]) @ D2 \
            + h * (-2 * P[3] + 12 * P[4]) @ D3

    def kernel_steps(self, n):
        """Return the state after n kernel steps and the kernel's largest estimate."""
        stepper = self.sim.stepper
        x = self.x0.copy()
        stepper.estimate = 0.0
        stepper.advance(x, self.u, self.dt / n, n)
        return x, stepper.estimate

    def error(self, x, x_ref):
        """Return the weighted q, qdot error."""
        nd = 2 * self.n_q
        return float(np.max(np.abs(x[:nd] - x_ref[:nd]) * self.weights))


def main():
    """Print the table and the modal split."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--case', nargs=2, default=['simply_supported', '0.20'])
    parser.add_argument('--n-ritz', type=int, default=5)
    parser.add_argument('--at', type=int, default=60, help='control periods run before')
    parser.add_argument('--quick', action='store_true', help='1 and 8 steps against 256')
    args = parser.parse_args()
    counts, reference_steps = ((1, 8), 256) if args.quick else (COUNTS, 4096)
    scene = step_scene(args.case[0], float(args.case[1]),
                       **{'scene.fidelity': 'exact', 'scene.n_ritz': args.n_ritz,
                          'integrator.tolerance': 1e-6, 'integrator.method': 'auto'})
    sim = Simulator(scene)
    for _ in range(args.at):
        sim.step()
    period = Period(sim)
    x_ref, _ = period.kernel_steps(reference_steps)
    print(f'{args.case[0]} {args.case[1]}, exact n_r {args.n_ritz}, period {args.at}: the '
          f'controller runs {sim.stepper.substeps} steps; local tolerance '
          f'{sim.stepper.tolerance:.3g}\n')
    print('| steps | etdrk4_linearized error | its estimate | EXPRB43 error |')
    print('|---|---|---|---|')
    for n in counts:
        x, estimate = period.kernel_steps(n)
        y = period.x0.copy()
        for _ in range(n):
            y = period.exprb43(y, period.dt / n)
        print(f'| {n} | {period.error(x, x_ref):.2e} | {estimate:.2e} | '
              f'{period.error(y, x_ref):.2e} |')
    nd = 2 * period.n_q
    A = np.empty(nd * nd)
    sim.stepper.linear_part(period.x0, period.u, A)
    values, vectors = np.linalg.eig(A.reshape(nd, nd))
    x, _ = period.kernel_steps(8)
    parts = np.linalg.solve(vectors, x[:nd] - x_ref[:nd])
    sizes = [abs(c) * np.linalg.norm(vectors[:, i] * period.weights)
             for i, c in enumerate(parts)]
    order = np.argsort(-np.abs(values))
    print('\nThe 8-step error over the modes (|lambda|/2pi, damping ratio: weighted size):')
    print(', '.join(f'{abs(values[i]) / 2 / np.pi:.0f} Hz, {-values[i].real / abs(values[i]):.2f}'
                    f': {sizes[i]:.1e}' for i in order if values[i].imag >= 0))


if __name__ == '__main__':
    main()
