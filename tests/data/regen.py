#!/usr/bin/python3
"""Regenerates, or checks, what can be regenerated of the simulated records in
tests/data (each described by its .json beside it).

    tests/data/regen.py [--build build] [--write]

Every record here is a simulation; none is from a real rig. What the .json
files do not keep is how the inputs were drawn (the input design and its
random stream) and the noise's random stream: the inputs (the t and input
columns) and the noise realisations are therefore the files' own, kept as
they are, and cannot be regenerated. What is regenerated is what follows
from them and from the .json:

- the outputs of the noise-free records (two_tank, rotary_pendulum): the
  model plugin with the true parameters and initial state (riccati simulate,
  CVODE BDF at rtol 1e-12), over the file's own inputs: they must agree to
  1e-8 of each output's range, and --write writes them;
- the outputs of flexible_manipulator, quantised as its .json says (encoder
  angles to 0.01 degree): each sample must be within one quantum of the
  simulation (a value on a boundary may round either way), and --write writes
  them;
- the noisy records (two_tank_noisy, rotary_pendulum_noisy, and rotating_arm,
  simulated from the .json's true_system, which is not a plugin): the
  residual file - simulation must be noise of the stated standard deviation
  (its sample mean within 4 standard errors of 0, its sample variance within
  the chi-square 99.99 % interval). They are checked, never written: their
  realisation of the noise is what the tests' seeds-fixed outcomes rest on.
- --write writes two_tank.mat again (MAT v5, T, U, Y) with the CSV's
  columns; that the .mat copies equal their CSVs is dataset_test's check
  (DatasetFixtures.*MatEqualsCsv).

It starts its own riccatid (from --build, on a free loopback port, with a
temporary data directory) and stops it. Exit status 0 when every check holds.
"""
import argparse
import csv
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time

from statistics import NormalDist

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))

NOISE_FREE_TOLERANCE = 1e-8  # of each output's range: the integrators differ, the model does not


def read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    header = rows[0]
    data = np.array([[float(v) for v in r] for r in rows[1:]])
    return header, data


def write_csv(path, header, data):
    with open(path, "w", newline="") as f:
        f.write(",".join(header) + "\n")
        for row in data:
            f.write(",".join("%.17g" % v for v in row) + "\n")  # as the files were written: exact


class Daemon:
    def __init__(self, build, work):
        self.work = work
        port_file = os.path.join(work, "port")
        self.log = open(os.path.join(work, "riccatid.log"), "w")
        self.process = subprocess.Popen(
            [os.path.join(build, "bin", "riccatid"), "--listen", "127.0.0.1:0", "--port-file", port_file,
             "--data-dir", os.path.join(work, "data"), "--models-dir", os.path.join(build, "lib", "riccati", "models")],
            stderr=self.log)
        for _ in range(300):
            if os.path.exists(port_file) and open(port_file).read().strip():
                self.server = "127.0.0.1:" + open(port_file).read().strip()
                return
            if self.process.poll() is not None:
                raise RuntimeError(f"riccatid exited ({self.process.returncode}): see {self.log.name}")
            time.sleep(0.1)
        raise RuntimeError("riccatid did not write its port")

    def stop(self):
        self.process.send_signal(signal.SIGTERM)
        self.process.wait(timeout=60)
        self.log.close()


def simulate(daemon, build, meta, csv_path, out_path):
    """The model's outputs over the file's inputs, with the .json's truth."""
    model = meta["model"].split()[0]
    theta = ",".join(repr(float(meta["parameters"][p])) for p in meta["parameter_order"])
    x0 = meta.get("true_initial_state", [0.0] * len(meta["states"]))
    subprocess.run([os.path.join(build, "bin", "riccati"), "--server", daemon.server, "simulate", "-m", model,
                    "--inputs", csv_path, "--input-columns", *meta["inputs"], "--params", theta,
                    "--x0", ",".join(repr(float(v)) for v in x0), "--integrator", "cvode-bdf", "--rtol", "1e-12",
                    "--atol", "1e-14", "-o", out_path], check=True)
    header, data = read_csv(out_path)
    return np.column_stack([data[:, header.index(y)] for y in meta["outputs"]])


def rotating_arm_truth(meta, t, current):
    """The .json's true_system (not the plugin's neural friction), RK4 with 100
    steps a sample and the current held over each."""
    s = meta["true_system"]
    minv, b, fc, fs, vs = s["Minv"], s["b"], s["Fc"], s["Fs"], s["vs"]

    def f(x, i):
        v = x[1]
        friction = (fc + (fs - fc) * math.exp(-(v / vs) ** 2)) * math.tanh(v / 0.005)
        return np.array([v, minv * (i - b * v - friction)])

    x = np.zeros(2)
    out = np.zeros((len(t), 2))
    out[0] = x
    for k in range(1, len(t)):
        h = (t[k] - t[k - 1]) / 100
        for _ in range(100):
            k1 = f(x, current[k - 1])
            k2 = f(x + h / 2 * k1, current[k - 1])
            k3 = f(x + h / 2 * k2, current[k - 1])
            k4 = f(x + h * k3, current[k - 1])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k] = x
    return out


def chi2_quantile(p, dof):
    """Wilson and Hilferty's approximation: relative error below 1e-3 at
    these degrees of freedom (1000 and more), far inside the interval."""
    z = NormalDist().inv_cdf(p)
    return dof * (1 - 2 / (9 * dof) + z * math.sqrt(2 / (9 * dof))) ** 3


def check_noise(name, residual, stds, failures):
    n = residual.shape[0]
    for j, sigma in enumerate(stds):
        r = residual[:, j]
        mean_bound = 4 * sigma / math.sqrt(n)
        lo, hi = (chi2_quantile(q, n - 1) / (n - 1) * sigma ** 2 for q in (5e-5, 1 - 5e-5))
        var = r.var(ddof=1)
        ok = abs(r.mean()) < mean_bound and lo < var < hi
        print(f"{name}: output {j + 1}: residual mean {r.mean():.3g} (|.| < {mean_bound:.3g}), "
              f"std {math.sqrt(var):.4g} (stated {sigma}; [{math.sqrt(lo):.4g}, {math.sqrt(hi):.4g}])"
              f" {'ok' if ok else 'FAILS'}")
        if not ok:
            failures.append(f"{name}: output {j + 1} is not noise of std {sigma} about the simulation")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default=os.path.join(ROOT, "build"))
    parser.add_argument("--write", action="store_true", help="write the regenerated outputs into the files")
    args = parser.parse_args()
    failures = []
    with tempfile.TemporaryDirectory(prefix="riccati-regen-") as work:
        daemon = Daemon(args.build, work)
        try:
            for json_name in sorted(f for f in os.listdir(HERE) if f.endswith(".json")):
                meta = json.load(open(os.path.join(HERE, json_name)))
                name = meta["name"]
                csv_path = os.path.join(HERE, meta["csv"])
                header, data = read_csv(csv_path)
                t = data[:, header.index("t")]
                columns = [header.index(y) for y in meta["outputs"]]
                stored = data[:, columns]
                if "true_system" in meta:
                    simulated = rotating_arm_truth(meta, t, data[:, header.index(meta["inputs"][0])])
                else:
                    simulated = simulate(daemon, args.build, meta, csv_path, os.path.join(work, name + ".csv"))
                stds = meta.get("noise_std", [0.0] * len(columns))
                quantum = math.radians(0.01) if "quantised to 0.01 degree" in meta.get("measurement", "") else 0.0
                if quantum > 0:
                    regenerated = np.round(simulated / quantum) * quantum
                    off = np.abs(stored - regenerated).max() / quantum
                    exact = np.mean(np.abs(stored - regenerated) < 1e-3 * quantum)
                    ok = off <= 1 + 1e-6
                    print(f"{name}: quantised outputs within {off:.3g} quanta of the simulation "
                          f"({100 * exact:.2f} % of samples the same quantum) {'ok' if ok else 'FAILS'}")
                elif any(s > 0 for s in stds):
                    check_noise(name, stored - simulated, stds, failures)
                    regenerated, ok = None, True
                else:
                    regenerated = simulated
                    span = stored.max(axis=0) - stored.min(axis=0)
                    off = (np.abs(stored - simulated).max(axis=0) / span).max()
                    ok = off < NOISE_FREE_TOLERANCE
                    print(f"{name}: outputs within {off:.3g} of their range of the simulation "
                          f"(< {NOISE_FREE_TOLERANCE}) {'ok' if ok else 'FAILS'}")
                if not ok:
                    failures.append(f"{name}: the stored outputs are not the model's")
                if args.write and regenerated is not None:
                    data[:, columns] = regenerated
                    stored = regenerated
                    write_csv(csv_path, header, data)
                    print(f"{name}: wrote {meta['csv']}")
                    if "mat" in meta:
                        import scipy.io  # python3-scipy: for --write only
                        scipy.io.savemat(os.path.join(HERE, meta["mat"]), {
                            "T": t.reshape(1, -1), "U": data[:, [header.index(u) for u in meta["inputs"]]].T,
                            "Y": stored.T}, format="5")
                        print(f"{name}: wrote {meta['mat']}")
        finally:
            daemon.stop()
    for f in failures:
        print("FAILED:", f, file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
