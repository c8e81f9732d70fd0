#!/usr/bin/python3
"""The picture of an output-error fit, made the way a user would get it.

Starts build/bin/riccatid on a free loopback port with a throw-away data
directory, identifies the two-tank model on its noisy record
(tests/data/two_tank_noisy.csv) by output error from Hensen's start
[20 20 1 1] with the initial states estimated, takes the result as CSV
(`riccati result JOB --format csv`) and draws, per output, the measured and
the simulated level, then the normalised residuals and their
autocorrelation with its 95 % band. Writes docs/figures/two_tank_fit.png.

    /usr/bin/python3 docs/figures/two_tank_fit.py     # Debian's python3-matplotlib
"""
import csv
import io
import os
import subprocess
import sys
import tempfile
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BIN = os.path.join(ROOT, "build", "bin")
OUT = os.path.join(ROOT, "docs", "figures", "two_tank_fit.png")


def riccati(server, *args):
    return subprocess.run([os.path.join(BIN, "riccati"), "--server", server, *args], check=True,
                          capture_output=True, text=True).stdout


def main():
    with tempfile.TemporaryDirectory() as work:
        port_file = os.path.join(work, "port")
        daemon = subprocess.Popen([os.path.join(BIN, "riccatid"), "--listen", "127.0.0.1:0", "--data-dir",
                                   os.path.join(work, "data"), "--port-file", port_file, "--log-level", "warn"])
        try:
            for _ in range(500):
                if os.path.exists(port_file) and open(port_file).read().strip():
                    break
                time.sleep(0.01)
            server = "127.0.0.1:" + open(port_file).read().strip()
            job = riccati(server, "identify", "--method", "oe", "--model", "two_tank", "--data",
                          os.path.join(ROOT, "tests", "data", "two_tank_noisy.csv"), "--inputs", "F1,F2",
                          "--outputs", "h1,h2", "--theta0", "20,20,1,1", "--output-sigma", "0.005,0.005",
                          "--estimate-x0", "--no-wait").strip()
            riccati(server, "job", "watch", job)
            table = riccati(server, "result", job)
            rows = list(csv.DictReader(io.StringIO(riccati(server, "result", job, "--format", "csv"))))
        finally:
            daemon.terminate()
            daemon.wait(timeout=30)

    t = np.array([float(r["t"]) for r in rows])
    outputs = ["h1", "h2"]
    # The parameter table's rows (the first row of each name; the correlation table repeats them).
    estimate = {}
    for line in table.splitlines():
        words = line.split()
        if words[:1] and words[0] in ("A1", "A2", "k1", "k2") and words[0] not in estimate:
            estimate[words[0]] = f"{words[0]} = {words[2]} ± {words[3]}"
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), gridspec_kw={"height_ratios": [2, 1, 1]})
    for j, name in enumerate(outputs):
        measured = np.array([float(r["y." + name]) for r in rows])
        model = np.array([float(r["y_model." + name]) for r in rows])
        residual = np.array([float(r["residual_normalised." + name]) for r in rows])
        ax = axes[0, j]
        ax.plot(t, measured, ".", ms=2, color="0.55", label="measured")
        ax.plot(t, model, "-", lw=1.2, color="tab:blue", label="output-error model")
        ax.set_title(f"{name}: measured and simulated")
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"{name} (m)")
        ax.legend(loc="best", fontsize=8)
        ax = axes[1, j]
        ax.plot(t, residual, ",", color="tab:red")
        ax.axhline(0, color="k", lw=0.6)
        ax.set_title(f"{name}: normalised residual (y - y_model) / sigma")
        ax.set_xlabel("t (s)")
        ax = axes[2, j]
        r = residual - residual.mean()
        lags = np.arange(1, 21)
        acf = np.array([np.dot(r[:-k], r[k:]) for k in lags]) / np.dot(r, r)
        band = 1.96 / np.sqrt(len(r))
        ax.bar(lags, acf, color="tab:red", width=0.6)
        ax.axhspan(-band, band, color="tab:green", alpha=0.2, label="95 % band of white noise")
        ax.set_title(f"{name}: residual autocorrelation")
        ax.set_xlabel("lag (samples)")
        ax.legend(loc="best", fontsize=8)
    fig.suptitle("riccati identify --method oe on the noisy two-tank record, from theta0 = [20 20 1 1]\n" +
                 "estimate ± standard error: " + ",  ".join(estimate.values()) +
                 "\n(truth: A1 = 10, A2 = 5, k1 = 0.0791, k2 = 0.1342; noise sigma 0.005 m)", fontsize=9)
    fig.tight_layout()
    fig.savefig(OUT, dpi=110)
    print(OUT)


if __name__ == "__main__":
    sys.exit(main())
