"""
The compiled kernel against a plain C loop: cost per internal step of each stepper.

The floor is a plain C RK4 loop of the one-term model (bench/c_floor/rk4_floor.c, scalar code,
every constant local): the cost a hand-written loop pays per step. It is timed with the
kernel's steppers on the default scene at the paper's level (``scene.fidelity: paper``, the one
term the floor codes; the shipped default is the exact kinematics), in one process,
interleaved; the table gives each stepper's cost per step and its ratio to the floor.

The floor is compiled here with the package's flags. Before timing, it is checked to follow
the kernel's 'rk4' trajectory (same model, same steps) to round-off, so both compute the same
thing. Cost = process CPU time per step (min of --repeats; a shared host only adds time).
Run: python bench/kernel_floor.py (~20 s); ``--quick``: one short round (a smoke run).
"""

import argparse
import ctypes
import os
import subprocess
import tempfile
import time

from det_sim_ros.physics.model import build_model
from det_sim_ros.physics.statics import initial_state
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.integrators import get_method, make_stepper, StepControl
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
PAPER = {'scene.fidelity': 'paper'}   # the one-term model the floor codes
FIELDS = ('m_tot', 'Mb', 'K', 'D', 'm', 'c2', 'e4', 'length', 'l0', 'VY', 'C0', 'V', 'E_M',
          'eta_M', 'eta_v', 'Rs', 'Rp', 'v')


class FloorParams(ctypes.Structure):
    _fields_ = [(name, ctypes.c_double) for name in FIELDS]


def build_floor(tmp):
    lib = os.path.join(tmp, 'rk4_floor.so')
    subprocess.run(['gcc', '-O3', '-std=c99', '-fno-math-errno', '-shared', '-fPIC',
                    os.path.join(HERE, 'c_floor', 'rk4_floor.c'), '-o', lib], check=True)
    floor = ctypes.CDLL(lib).rk4_floor
    floor.restype = ctypes.c_double
    floor.argtypes = [ctypes.POINTER(FloorParams), ctypes.POINTER(ctypes.c_double),
                      ctypes.c_double, ctypes.c_int64]
    return floor


def floor_params(model, volts):
    a = model.arrays
    if not (a.n_q == 1 and a.kinematics[0] == 0 and a.creep and a.rc_source
            and a.power_monitor):
        raise SystemExit('kernel_floor: the floor codes the one-term model with creep, an RC '
                         'source and the power monitor; this scene is not that model')
    return FloorParams(m_tot=0.0, Mb=a.Mb[0, 0], K=a.K[0, 0], D=a.D[0, 0], m=a.mi_val[0],
                       c2=a.c2[0], e4=a.e4[0], length=a.length[0], l0=a.l0[0], VY=a.VY[0],
                       C0=a.C0[0], V=a.volume[0], E_M=a.E_M[0], eta_M=a.eta_M[0],
                       eta_v=a.eta_v[0], Rs=a.Rs[0], Rp=a.Rp[0], v=volts)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--repeats', type=int, default=7)
    parser.add_argument('--steps', type=int, default=200_000)
    parser.add_argument('--quick', action='store_true', help='one round of 2000 steps')
    args = parser.parse_args(argv)
    if args.quick:
        args.repeats, args.steps = 1, 2000
    model = build_model(load_scene('default', PAPER))
    volts, h = 1500.0, 2e-6      # stable for explicit RK4 on the RC charge (tau ~ 28 us)
    x0 = initial_state(model)
    x0[0], x0[1] = 4e-3, 0.1      # a buckled beam in motion
    u = np.array([volts])
    with tempfile.TemporaryDirectory() as tmp:
        floor = build_floor(tmp)
        params = floor_params(model, volts)
        # same model, same method, same steps: the trajectories agree to round-off
        xf = (ctypes.c_double * 6)(*x0)
        floor(params, xf, h, 1000)
        xk = x0.copy()
        stepper = make_stepper(model, get_method('rk4'), StepControl(1), 1e-3)
        assert stepper.advance(xk, u, h, 1000) == 0
        scale = np.maximum(np.abs(xk), 1e-30)
        deviation = float(np.max(np.abs(np.array(xf[:]) - xk) / scale))
        print(f'floor vs kernel rk4 after 1000 steps: max relative deviation {deviation:.1e}')
        assert deviation < 1e-9, 'the floor does not compute the same model'
        names = ('rk4', 'etdrk4', 'dp5')
        steppers = {n: make_stepper(model, get_method(n), StepControl(1), 1e-3) for n in names}
        best = {n: np.inf for n in ('floor',) + names}
        for _ in range(args.repeats):     # interleaved: host load hits all alike
            xf = (ctypes.c_double * 6)(*x0)
            best['floor'] = min(best['floor'], floor(params, xf, h, args.steps) / args.steps)
            for n in names:
                x = x0.copy()
                t0 = time.process_time()
                steppers[n].advance(x, u, h, args.steps)
                best[n] = min(best[n], (time.process_time() - t0) / args.steps)
    print('| stepper | ns per internal step (min) | × floor |')
    print('|---|---|---|')
    for n, cost in best.items():
        label = 'plain C RK4 (floor)' if n == 'floor' else f'kernel {n}'
        print(f'| {label} | {cost * 1e9:.0f} | {cost / best["floor"]:.2f} |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
