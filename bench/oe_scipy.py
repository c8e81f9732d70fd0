#!/usr/bin/python3
"""Output error on the two-tank record with scipy.optimize.least_squares.

The scipy side of bench/oe_versus_scipy.sh: the problem riccati's
TwoTankOutputError benchmark solves (bench/engine_bench.cpp), written as a
scipy user would write it. Needs only Debian 12's python3-scipy and
python3-numpy (apt-get install python3-scipy; run with /usr/bin/python3,
not a virtual environment's python):

    /usr/bin/python3 bench/oe_scipy.py --integrator odeint --jacobian sensitivity

The problem, as riccati's output_error() has it with its defaults:
  model     h1' = (F1 - k1 r(h1)) / A1,  h2' = (F2 + k1 r(h1) - k2 r(h2)) / A2,
            r(h) = sqrt(h) for h > 0, else 0 (models/two_tank/two_tank.cpp);
            outputs h1, h2; theta = [A1 A2 k1 k2]
  data      tests/data/two_tank.csv: 2000 samples at 1 s, noise-free; the
            inputs held constant over each sample interval (zero-order hold);
            x0 = the first measurement, not estimated
  criterion 1/2 sum_k ||y_model(t_k) - y_k||^2 over all 2000 samples
  start     theta0 = [20 20 1 1], bounds theta >= 0
  stopping  ftol 1e-14, gtol 1e-14, xtol 1e-12 (riccati's OptimizerSettings:
            function, gradient, parameter tolerance), at most 200 iterations

Integrators (--integrator):
  rk4        the classic RK4 riccati uses by default, 10 equal substeps per
             1 s sample: the very same discretisation, so the same criterion
             to rounding. Pure Python (floats, not numpy arrays: faster for 2
             or 10 states).
  odeint     scipy.integrate.odeint (LSODA, ODEPACK), one call per stretch of
             constant input (43 of them), rtol 1e-13, atol 1e-15: tight enough
             that its error at the truth (3e-13 on the outputs) is that of
             riccati's RK4 (2e-13), see --check.
  solve_ivp  scipy.integrate.solve_ivp (DOP853), the same stretches, rtol
             1e-13, atol 1e-15 (its error at the truth is no better than
             about 1e-12 at any rtol: 1.1e-12 here).

Jacobians (--jacobian):
  2-point      least_squares' default finite differences (4 more simulations
               per Jacobian)
  sensitivity  the forward sensitivities S = dx/dtheta integrated with the
               states, S' = f_x S + f_theta, S(0) = 0 (what riccati does): one
               simulation of 10 values per Jacobian, exact for rk4 (the
               derivative of the discretised solution), within the
               integrator's tolerance for odeint and solve_ivp

Prints one JSON object: the estimate, its worst relative error against the
truth in two_tank.json, evaluations, and the wall and CPU time of the whole
least_squares call as the median of --repetitions runs (data loaded once,
before the clock).
"""
import argparse
import json
import math
import os
import statistics
import sys
import time

import numpy as np
import scipy
from scipy.integrate import odeint, solve_ivp
from scipy.optimize import least_squares

HERE = os.path.dirname(os.path.abspath(__file__))
DATA_DIR = os.path.join(HERE, "..", "tests", "data")


def load(data_dir):
    raw = np.loadtxt(os.path.join(data_dir, "two_tank.csv"), delimiter=",", skiprows=1)
    with open(os.path.join(data_dir, "two_tank.json")) as f:
        meta = json.load(f)
    truth = np.array([meta["parameters"][name] for name in meta["parameter_order"]])
    return raw[:, 0], raw[:, 1:3], raw[:, 3:5], truth


def rhs(h1, h2, A1, A2, k1, k2, F1, F2):
    """The model's right-hand side (two_tank.cpp)."""
    q1 = k1 * math.sqrt(h1) if h1 > 0.0 else 0.0
    q2 = k2 * math.sqrt(h2) if h2 > 0.0 else 0.0
    return (F1 - q1) / A1, (F2 + q1 - q2) / A2


def rhs_sensitivity(z, A1, A2, k1, k2, F1, F2):
    """[x; S] with S = dx/dtheta (2 x 4, row-major after x): S' = f_x S + f_theta."""
    h1, h2, s10, s11, s12, s13, s20, s21, s22, s23 = z
    r1 = math.sqrt(h1) if h1 > 0.0 else 0.0
    r2 = math.sqrt(h2) if h2 > 0.0 else 0.0
    d1 = 0.5 / r1 if h1 > 0.0 else 0.0  # d r / d h, 0 where r is held at 0
    d2 = 0.5 / r2 if h2 > 0.0 else 0.0
    f1 = (F1 - k1 * r1) / A1
    f2 = (F2 + k1 * r1 - k2 * r2) / A2
    a11 = -k1 * d1 / A1  # f_x = [[a11, 0], [a21, a22]]
    a21 = k1 * d1 / A2
    a22 = -k2 * d2 / A2
    return (f1, f2,
            a11 * s10 - f1 / A1, a11 * s11, a11 * s12 - r1 / A1, a11 * s13,
            a21 * s10 + a22 * s20, a21 * s11 + a22 * s21 - f2 / A2,
            a21 * s12 + a22 * s22 + r1 / A2, a21 * s13 + a22 * s23 - r2 / A2)


class Rk4:
    """RK4 with `substeps` equal steps per sample interval, as riccati's."""

    def __init__(self, t, U, substeps):
        self.t, self.U, self.substeps = t, U, substeps

    def simulate(self, x0, theta):
        A1, A2, k1, k2 = (float(v) for v in theta)
        t, U, n = self.t, self.U, self.substeps
        y = np.empty((len(t), 2))
        h1, h2 = float(x0[0]), float(x0[1])
        y[0] = h1, h2
        for k in range(1, len(t)):
            h = (t[k] - t[k - 1]) / n
            F1, F2 = float(U[k - 1, 0]), float(U[k - 1, 1])
            for _ in range(n):
                a1, b1 = rhs(h1, h2, A1, A2, k1, k2, F1, F2)
                a2, b2 = rhs(h1 + 0.5 * h * a1, h2 + 0.5 * h * b1, A1, A2, k1, k2, F1, F2)
                a3, b3 = rhs(h1 + 0.5 * h * a2, h2 + 0.5 * h * b2, A1, A2, k1, k2, F1, F2)
                a4, b4 = rhs(h1 + h * a3, h2 + h * b3, A1, A2, k1, k2, F1, F2)
                h1 += h / 6.0 * (a1 + 2.0 * (a2 + a3) + a4)
                h2 += h / 6.0 * (b1 + 2.0 * (b2 + b3) + b4)
            y[k] = h1, h2
        return y

    def simulate_sensitivity(self, x0, theta):
        A1, A2, k1, k2 = (float(v) for v in theta)
        t, U, n = self.t, self.U, self.substeps
        out = np.empty((len(t), 10))
        z = [float(x0[0]), float(x0[1])] + [0.0] * 8
        out[0] = z
        for k in range(1, len(t)):
            h = (t[k] - t[k - 1]) / n
            F1, F2 = float(U[k - 1, 0]), float(U[k - 1, 1])
            for _ in range(n):
                c1 = rhs_sensitivity(z, A1, A2, k1, k2, F1, F2)
                c2 = rhs_sensitivity([a + 0.5 * h * b for a, b in zip(z, c1)], A1, A2, k1, k2, F1, F2)
                c3 = rhs_sensitivity([a + 0.5 * h * b for a, b in zip(z, c2)], A1, A2, k1, k2, F1, F2)
                c4 = rhs_sensitivity([a + h * b for a, b in zip(z, c3)], A1, A2, k1, k2, F1, F2)
                z = [a + h / 6.0 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(z, c1, c2, c3, c4)]
            out[k] = z
        return out


def constant_input_stretches(U):
    """[(a, b)]: the input is U[a] over [t_a, t_b] (zero-order hold)."""
    changes = [k for k in range(1, len(U)) if np.any(U[k] != U[k - 1])]
    edges = [0] + changes + [len(U) - 1]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


class Adaptive:
    """odeint or solve_ivp over each stretch of constant input, out at the samples."""

    def __init__(self, t, U, kind, rtol, atol):
        self.t, self.U, self.kind, self.rtol, self.atol = t, U, kind, rtol, atol
        self.stretches = constant_input_stretches(U)

    def _run(self, fun, z0, theta):
        t, U = self.t, self.U
        theta = tuple(float(v) for v in theta)
        out = np.empty((len(t), len(z0)))
        out[0] = z0
        z = np.asarray(z0, dtype=float)
        for a, b in self.stretches:
            args = theta + (float(U[a, 0]), float(U[a, 1]))
            if self.kind == "odeint":
                sol = odeint(fun, z, t[a:b + 1], args=args, rtol=self.rtol, atol=self.atol, tfirst=True,
                             mxstep=100000)
                out[a + 1:b + 1] = sol[1:]
            else:
                sol = solve_ivp(fun, (t[a], t[b]), z, method="DOP853", t_eval=t[a + 1:b + 1], args=args,
                                rtol=self.rtol, atol=self.atol)
                if not sol.success:
                    raise RuntimeError(sol.message)
                out[a + 1:b + 1] = sol.y.T
            z = out[b].copy()
        return out

    def simulate(self, x0, theta):
        return self._run(lambda _t, x, *p: rhs(x[0], x[1], *p), list(x0), theta)

    def simulate_sensitivity(self, x0, theta):
        return self._run(lambda _t, z, *p: rhs_sensitivity(z, *p), list(x0) + [0.0] * 8, theta)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--integrator", choices=["rk4", "odeint", "solve_ivp"], default="odeint")
    p.add_argument("--jacobian", choices=["2-point", "sensitivity"], default="2-point")
    p.add_argument("--substeps", type=int, default=10, help="rk4: steps per sample (riccati's default 10)")
    p.add_argument("--rtol", type=float, default=1e-13, help="odeint, solve_ivp")
    p.add_argument("--atol", type=float, default=1e-15, help="odeint, solve_ivp")
    p.add_argument("--repetitions", type=int, default=5)
    p.add_argument("--data-dir", default=DATA_DIR)
    p.add_argument("--check", action="store_true",
                   help="also the integrator's largest output error at the truth, against the record")
    args = p.parse_args()

    t, U, Y, truth = load(args.data_dir)
    x0 = Y[0].copy()  # the first measurement, as the riccati benchmark's Experiment::x0
    if args.integrator == "rk4":
        sim = Rk4(t, U, args.substeps)
    else:
        sim = Adaptive(t, U, args.integrator, args.rtol, args.atol)
    theta0 = np.array([20.0, 20.0, 1.0, 1.0])
    counts = {"simulations": 0, "sensitivity_simulations": 0}

    def residuals(theta):
        counts["simulations"] += 1
        return (sim.simulate(x0, theta) - Y).ravel()

    def jacobian(theta):
        counts["sensitivity_simulations"] += 1
        z = sim.simulate_sensitivity(x0, theta)
        return z[:, 2:].reshape(len(t) * 2, 4)  # row 2k + i: d h_i(t_k) / d theta

    jac = "2-point" if args.jacobian == "2-point" else jacobian
    walls, cpus, result = [], [], None
    for _ in range(args.repetitions):
        counts.update(simulations=0, sensitivity_simulations=0)
        w0, c0 = time.perf_counter(), time.process_time()
        result = least_squares(residuals, theta0, jac=jac, bounds=(0.0, np.inf), method="trf",
                               ftol=1e-14, gtol=1e-14, xtol=1e-12, max_nfev=None)
        cpus.append(time.process_time() - c0)
        walls.append(time.perf_counter() - w0)

    out = {
        "solver": "scipy.optimize.least_squares (trf)",
        "integrator": args.integrator,
        "integrator_settings": ({"substeps": args.substeps} if args.integrator == "rk4"
                                else {"rtol": args.rtol, "atol": args.atol}),
        "jacobian": args.jacobian,
        "theta": result.x.tolist(),
        "truth": truth.tolist(),
        "worst_rel_error": float(np.max(np.abs((result.x - truth) / truth))),
        "cost": float(result.cost),
        "status": int(result.status),
        "message": result.message,
        "nfev": int(result.nfev),
        "njev": int(result.njev) if result.njev is not None else None,
        "simulations": counts["simulations"],
        "sensitivity_simulations": counts["sensitivity_simulations"],
        "repetitions": args.repetitions,
        "wall_s": statistics.median(walls),
        "cpu_s": statistics.median(cpus),
        "wall_s_each": walls,
        "cpu_s_each": cpus,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "scipy": scipy.__version__,
    }
    if args.check:
        out["output_error_at_truth"] = float(np.max(np.abs(sim.simulate(x0, truth) - Y)))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
