"""
Faults planted in the numerics one at a time, and the first test that fails on each.

Each row of ``FAULTS`` replaces one exact snippet of one source file with a wrong one: a
truncated series, a wrong weight, sign, factor or bound, a dropped term, the kind of slip a
refactor makes. For each, in a clone of this checkout's HEAD (your working tree is never
touched; uncommitted changes are not in it): plant it, rebuild the compiled core, run the suite
without ROS (``pytest -x -m "not ros"``), note the first failing test, restore. A fault no test
catches is a gap in the tests, or a change that changes nothing (then the code it touches is
dead: drop that code instead).

Run: python bench/planted_faults.py (~10 min on 2 cores: the unplanted baseline, then per fault
a rebuild and the tests up to the first failure; ``--only NAME ...`` for some). ``--quick``
only checks that every snippet is still in its file exactly once (no clone, no build, no test
run): the table follows the code.
"""

from __future__ import annotations

import argparse
import datetime
import os
import re
import subprocess
import sys
import tempfile
import time
from typing import NamedTuple

from checkouts import tree_env
from fidelity_choice import _commit, MACHINE

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CORE = 'det_sim_ros/core/_csrc/'


class Fault(NamedTuple):
    name: str
    path: str        # relative to the repository root
    snippet: str     # exactly once in the file
    planted: str
    breaks: str      # what the fault gets wrong


FAULTS = (
    Fault('taylor_cut_short', CORE + 'stepping/matrix_phi.c', '#define TAYLOR_DEGREE 13',
          '#define TAYLOR_DEGREE 7', "the phi functions' Taylor series cut at degree 7"),
    Fault('too_few_doublings', CORE + 'stepping/matrix_phi.c', '#define PHI_NORM 0.5',
          '#define PHI_NORM 8.0', 'the phi functions taken at a norm 16x larger'),
    Fault('doubling_factorial', CORE + 'stepping/matrix_phi.c',
          'fact *= (double)(k - j + 1);', 'fact *= (double)(k - j + 2);',
          "a factorial in the phi functions' doubling formula"),
    Fault('unbalance_inverted', CORE + 'stepping/matrix_phi.c', '* (d[i] / d[j]);',
          '* (d[j] / d[i]);', "the balancing undone with the scaling's inverse"),
    Fault('krogstad_weight', 'det_sim_ros/sim/integrators.py', '(4, 3, 3, 1.0, 4.0),',
          '(4, 3, 3, 1.0, 3.0),', "one weight of Krogstad's ETDRK4 table"),
    Fault('control_safety', CORE + 'stepping/period.c', '#define CTL_SAFETY 0.5',
          '#define CTL_SAFETY 2.0', 'the step control aiming at twice its tolerance'),
    Fault('bdf_kappa', CORE + 'stepping/bdf.c', '{0.0, -0.1850,', '{0.0, -0.1500,',
          'the first-order NDF coefficient kappa_1'),
    Fault('bdf_error_constant', CORE + 'stepping/bdf.c',
          'KAPPA[k] * gamma + 1.0 / (double)(k + 1);',
          'KAPPA[k] * gamma + 1.0 / (double)(k + 2);', 'the BDF error constants'),
    Fault('linearization_kept_across_inputs', CORE + 'stepping/linear_part.c',
          'if (fabs(u[i] - lin->u_lin[i]) > st->options.refresh_input)',
          'if (0 && fabs(u[i] - lin->u_lin[i]) > st->options.refresh_input)',
          "the beams' linearization never taken anew when the voltage moves"),
    Fault('linearization_kept_across_states', CORE + 'stepping/linear_part.c',
          'if (fabs(x[k] - lin->x_lin[k]) * g->inv_scale[k] > st->options.refresh)',
          'if (0 && fabs(x[k] - lin->x_lin[k]) * g->inv_scale[k] > st->options.refresh)',
          "the beams' linearization never taken anew when the state moves"),
    Fault('electrostatic_force_halved', CORE + 'physics/physics.c',
          'vp = qp * d->inv_C0 * inv_lam2;\n        bracket = d->VY / 3.0 * (lam - inv_lam2 * '
          'inv_lam) - qp * vp * inv_lam;\n    } else {\n        vp = u[i];',
          'vp = qp * d->inv_C0 * inv_lam2;\n        bracket = d->VY / 3.0 * (lam - inv_lam2 * '
          'inv_lam) - 0.5 * qp * vp * inv_lam;\n    } else {\n        vp = u[i];',
          'the electrostatic force of a DET behind a resistor (many-term path)'),
    Fault('viscosity_doubled', CORE + 'physics/physics.c',
          '(eq 67) */\n    const double visc = d->volume * (d->E_M * eps + d->eta_v * lzd);',
          '(eq 67) */\n    const double visc = d->volume * (d->E_M * eps + 2 * d->eta_v * lzd);',
          "the DET's viscous stress (many-term path)"),
    Fault('leak_not_dissipated', CORE + 'physics/physics.c',
          'pw->p_diss += vp * vp * d->inv_Rp + ', 'pw->p_diss += 0.0 * vp * vp * d->inv_Rp + ',
          "the leakage resistor's power left out of the dissipation (many-term path)"),
    Fault('inertia_coupling_sign', CORE + 'physics/physics.c',
          'b.F -= m->mi_val[e] * b.J * hq;', 'b.F += m->mi_val[e] * b.J * hq;',
          "the DET mass's convective force, sign"),
    Fault('exact_force_order', CORE + 'physics/exact.c',
          'wpp * wpp * wp * inv_cos2 * inv_cos2;', 'wpp * wpp * wp * inv_cos2;',
          "a power of cos in the exact kinematics' bending force"),
    Fault('exact_convective_order', CORE + 'physics/exact.c',
          'f->wd[k] * inv_cos2 * inv_cs;', 'f->wd[k] * inv_cs;',
          "a power of cos in the exact kinematics' convective term"),
    Fault('quadrature_tail_dropped', CORE + 'physics/exact.c',
          '    for (; k < n; k++)\n        s0 += a[k] * b[k];',
          '    for (; k < n; k++)\n        s0 += 0.0 * a[k] * b[k];',
          "the last (n mod 4) quadrature points of the exact kinematics' sums"),
    Fault('leak_current_dropped', CORE + 'physics/outputs.c', '* vp + vp / d->Rp;',
          '* vp + 0.0 * vp / d->Rp;', 'the leakage current in the current output'),
    Fault('electric_energy_doubled', CORE + 'physics/outputs.c', '+ 0.5 * qp * qp / cap;',
          '+ 1.0 * qp * qp / cap;', 'the electric energy in the energy output'),
    Fault('amplifier_output_sign', CORE + 'physics/amplifier.c',
          's.v_out = vp + d->Rs * s.current;', 's.v_out = vp - d->Rs * s.current;',
          "the amplifier's output voltage at its current limit"),
)


def check_snippets(faults=FAULTS, root=REPO) -> list:
    """Return one line per fault whose snippet is not in its file exactly once."""
    problems = []
    for fault in faults:
        with open(os.path.join(root, fault.path), encoding='utf-8') as stream:
            count = stream.read().count(fault.snippet)
        if count != 1 or fault.planted == fault.snippet:
            problems.append(f'{fault.name}: the snippet is in {fault.path} {count} times')
    return problems


def _run_suite(tree: str) -> tuple:
    """Build the core in ``tree`` and run its suite without ROS; return (first failure, s)."""
    env = tree_env(tree)
    subprocess.run([sys.executable, 'setup.py', 'build_ext', '--inplace'], cwd=tree, env=env,
                   check=True, capture_output=True)
    started = time.monotonic()
    done = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-x', '-p', 'no:cacheprovider',
                           '-m', 'not ros', 'test'], cwd=tree, env=env, capture_output=True,
                          text=True)
    # (a parametrized test's id may hold spaces; pytest ends the line with ' - ' and the error)
    failed = re.findall(r'^(?:FAILED|ERROR) (.+?)(?: - .*)?$', done.stdout, re.MULTILINE)
    if done.returncode not in (0, 1) or (done.returncode == 1 and not failed):
        failed = [f'pytest exit {done.returncode}: {done.stdout.strip().splitlines()[-1:]}']
    return (failed[0] if failed else ''), time.monotonic() - started


def plant_all(faults, log=print) -> list:
    """Plant each fault in a clone of HEAD; return (fault, first failing test or '') rows."""
    rows = []
    with tempfile.TemporaryDirectory(prefix='det_sim_faults_') as folder:
        tree = os.path.join(folder, 'tree')
        subprocess.run(['git', 'clone', '--quiet', '--local', REPO, tree], check=True)
        failure, seconds = _run_suite(tree)
        if failure:
            raise SystemExit(f'the unplanted suite fails ({failure}): nothing to learn')
        log(f'baseline: the suite passes unplanted ({seconds:.0f} s)')
        for fault in faults:
            path = os.path.join(tree, fault.path)
            with open(path, encoding='utf-8') as stream:
                original = stream.read()
            try:
                with open(path, 'w', encoding='utf-8') as stream:
                    stream.write(original.replace(fault.snippet, fault.planted, 1))
                failure, seconds = _run_suite(tree)
            finally:
                with open(path, 'w', encoding='utf-8') as stream:
                    stream.write(original)
            log(f'{fault.name}: {failure or "NOT CAUGHT"} ({seconds:.0f} s)')
            rows.append((fault, failure))
    return rows


def table(rows, command: str) -> str:
    """Return the Markdown table of the rows, headed by date, commit, machine and command."""
    lines = [f'Measured {datetime.date.today().isoformat()}, commit {_commit()}, {MACHINE}, by '
             f'`{command}`:', '', '| fault | what it gets wrong | first test that fails |',
             '|---|---|---|']
    for fault, failure in rows:
        lines.append(f'| `{fault.name}` | {fault.breaks} | '
                     f'{f"`{failure}`" if failure else "**not caught**"} |')
    caught = sum(1 for _, failure in rows if failure)
    return '\n'.join(lines + ['', f'{caught} of {len(rows)} caught.'])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--only', nargs='+', metavar='NAME', help='plant only these faults')
    parser.add_argument('--quick', action='store_true',
                        help='only check that every snippet is in its file exactly once')
    args = parser.parse_args(argv)
    known = {fault.name: fault for fault in FAULTS}
    unknown = sorted(set(args.only or ()) - set(known))
    if unknown:
        parser.error(f'unknown fault(s) {", ".join(unknown)}; known: {", ".join(known)}')
    faults = [known[name] for name in args.only] if args.only else list(FAULTS)
    problems = check_snippets(faults)
    if problems:
        print('\n'.join(problems), file=sys.stderr)
        return 1
    if args.quick:
        print(f'{len(faults)} faults, each snippet once in its file')
        return 0
    rows = plant_all(faults, log=lambda line: print(line, file=sys.stderr, flush=True))
    print(table(rows, 'python bench/planted_faults.py'
                + (f' --only {" ".join(args.only)}' if args.only else '')))
    return 0 if all(failure for _, failure in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
