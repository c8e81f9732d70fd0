#!/usr/bin/python3
"""docs/python.md's worked example: Hensen's two-tank identification from
Python, validated, and drawn (measured and simulated levels, and the
difference). Writes docs/figures/two_tank_python.png, or the path given.

    /usr/bin/python3 -m pip install --no-build-isolation --no-deps --target /tmp/riccati-py ./client/python
    PYTHONPATH=/tmp/riccati-py /usr/bin/python3 docs/figures/two_tank_python.py [--server HOST:PORT] [OUT.png]

Without --server it starts build/bin/riccatid on a free loopback port with a
throw-away data directory (CTest runs it so, label docs).
"""
import os
import subprocess
import sys
import tempfile
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import riccati  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


# --- the example (docs/python.md shows this function) ---
def example(server, out_png):
    c = riccati.Client(server)
    ds = c.upload(os.path.join(ROOT, "tests/data/two_tank.csv"), inputs=["F1", "F2"], outputs=["h1", "h2"])

    # Hensen's settings (examples/two_tank_hensen.yaml), each keyword named as the CLI's flag.
    res = c.identify("two_tank", ds, filter="ekf", passes=10, x0="first", theta0=[20, 20, 1, 1],
                     p0=[0, 0, 10, 10, 10, 10], q=0, r=[1e-3, 1e-3], integrator="rk4", substeps=10,
                     progress=lambda job: print(f"\r{job.state} {100 * job.progress.fraction:3.0f} %", end=""))
    print()
    print(res.theta.to_frame().join(res.std))   # pandas, indexed by parameter name
    print(res.correlation.round(3))

    fit = c.validate("two_tank", ds, res)       # the identified model simulated over the inputs
    print(fit.fits)
    frame = fit.to_frame()                      # t, y.h1, y.h2, y_model.h1, y_model.h2, residual.h1, residual.h2

    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    for j, name in enumerate(["h1", "h2"]):
        ax = axes[0, j]
        ax.plot(frame.index, frame["y." + name], ".", ms=2, color="0.55", label="measured")
        ax.plot(frame.index, frame["y_model." + name], "-", lw=1.2, color="tab:blue", label="simulated")
        ax.set_title(f"{name}: fit {fit.fits.loc[name, 'fit_percent']:.2f} %")
        ax.set_ylabel(f"{name} (m)")
        ax.legend(loc="best", fontsize=8)
        ax = axes[1, j]
        ax.plot(frame.index, 1e3 * frame["residual." + name], lw=0.8, color="tab:red")
        ax.set_ylabel("measured - simulated (mm)")
        ax.set_xlabel("t (s)")
    theta = ", ".join(f"{n} = {v:.4g}" for n, v in res.theta.items())
    fig.suptitle(f"Two tanks, identified through riccati's Python client: {theta}", fontsize=10)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    c.close()
    return res, fit
# --- end of the example ---


def main(argv):
    out = os.path.join(ROOT, "docs", "figures", "two_tank_python.png")
    server = None
    args = list(argv)
    if "--server" in args:
        i = args.index("--server")
        server = args[i + 1]
        del args[i:i + 2]
    if args:
        out = args[0]
    if server:
        example(server, out)
        return
    with tempfile.TemporaryDirectory() as work:
        port_file = os.path.join(work, "port")
        daemon = subprocess.Popen([os.environ.get("RICCATI_DAEMON_BIN", os.path.join(ROOT, "build", "bin", "riccatid")),
                                   "--listen", "127.0.0.1:0", "--data-dir", os.path.join(work, "data"),
                                   "--port-file", port_file, "--log-level", "warn"])
        try:
            while not (os.path.exists(port_file) and open(port_file).read().strip()):
                if daemon.poll() is not None:
                    sys.exit(f"riccatid exited at start ({daemon.returncode})")
                time.sleep(0.01)
            example("127.0.0.1:" + open(port_file).read().strip(), out)
        finally:
            daemon.terminate()
            if daemon.wait(timeout=60) != 0:
                sys.exit(f"riccatid did not stop cleanly ({daemon.returncode})")


if __name__ == "__main__":
    main(sys.argv[1:])
