#!/usr/bin/python3
"""How long the workbench takes to plot a 100,000-point signal (issue 18's
target: under 1 s), in headless Chromium driven by Selenium against a real
riccatid (--http-listen, no tokens file: loopback is tenant "default").

  bench/plot_bench.py --riccatid build/bin/riccatid --models-dir build/lib/riccati/models [--points 100000] [--runs 5]

Uploads a CSV of one input and one output with --points samples through the
JSON API, then opens the dataset's page (#/datasets/<id>), which fetches
/api/v1/datasets/<id>/data and draws both signals with uPlot. Measured in the
page: from the data's arrival (the response body read: Response.text()
resolved) to both plots drawn (their canvases in place, then the next
animation frame, and their pixels checked not blank); and from the request
to drawn. Each run reloads the page. Prints every run and the medians.
"""
import argparse
import ctypes
import json
import math
import os
import shutil
import signal
import statistics
import subprocess
import tempfile
import time
import urllib.request

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

# Installed before the dataset page renders: when the /data body arrived, and
# when the plots are drawn (both canvases present, then a frame later).
HOOKS = """
window.__bench = {};
const text = Response.prototype.text;
Response.prototype.text = async function () {
  const started = performance.now();
  const body = await text.call(this);
  if (this.url.includes('/data')) { window.__bench.requested = window.__bench.requested || started; window.__bench.arrived = performance.now(); }
  return body;
};
const fetch0 = window.fetch;
window.fetch = function (url, ...rest) {
  if (String(url).includes('/data')) window.__bench.requested = performance.now();
  return fetch0.call(this, url, ...rest);
};
const expected = arguments[0];
new MutationObserver((_, observer) => {
  const canvases = document.querySelectorAll('#signal-plots canvas');
  if (canvases.length < expected || window.__bench.drawn) return;
  observer.disconnect();
  requestAnimationFrame(() => { window.__bench.drawn = performance.now(); });
}).observe(document.body, {childList: true, subtree: true});
"""

# Pixels of a canvas that are drawn (neither transparent nor white).
CANVAS_DRAWN = """
let drawn = 0;
for (const c of document.querySelectorAll('#signal-plots canvas')) {
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  for (let i = 0; i < d.length; i += 4) if (d[i + 3] > 0 && (d[i] < 240 || d[i + 1] < 240 || d[i + 2] < 240)) drawn++;
}
return drawn;
"""


def die_with_parent():
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)


def wait_for_file(path, process):
    for _ in range(600):
        if os.path.exists(path) and open(path).read().strip():
            return int(open(path).read().strip())
        if process.poll() is not None:
            raise RuntimeError(f"riccatid exited ({process.returncode})")
        time.sleep(0.1)
    raise RuntimeError(f"riccatid did not write {path}")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--riccatid", required=True)
    parser.add_argument("--models-dir", required=True)
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()

    work = tempfile.mkdtemp(prefix="riccati-plot-bench-")
    daemon = subprocess.Popen(
        [args.riccatid, "--listen", "127.0.0.1:0", "--port-file", os.path.join(work, "port"),
         "--http-listen", "127.0.0.1:0", "--http-port-file", os.path.join(work, "http_port"),
         "--data-dir", os.path.join(work, "data"), "--models-dir", args.models_dir, "--log-level", "warn"],
        preexec_fn=die_with_parent)
    driver = None
    try:
        http_port = wait_for_file(os.path.join(work, "http_port"), daemon)
        base = f"http://127.0.0.1:{http_port}"
        rows = ["t,u,y"] + [f"{k * 1e-3:.3f},{math.sin(k * 1e-3):.6f},{math.cos(k * 7e-4) + 0.01 * math.sin(k):.6f}"
                            for k in range(args.points)]
        request = urllib.request.Request(
            f"{base}/api/v1/datasets?name=signal.csv&format=csv&time_column=t&input_columns=u&output_columns=y",
            data=("\n".join(rows) + "\n").encode(), method="POST",
            headers={"Authorization": "Bearer -", "Content-Type": "application/octet-stream"})
        info = json.load(urllib.request.urlopen(request))
        print(f"dataset {info['id']}: {info.get('samples')} samples, 2 signals (2 plots of {args.points} points)")

        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                    "--window-size=1400,1000", "--force-device-scale-factor=1"):
            options.add_argument(arg)
        driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        driver.set_script_timeout(60)

        arrival_to_drawn, request_to_drawn = [], []
        for run in range(args.runs):
            driver.get(f"{base}/#/datasets")
            driver.execute_script("sessionStorage.setItem('riccati.token', '-');")
            driver.get(f"{base}/#/datasets")
            time.sleep(0.5)  # the list page settled
            driver.execute_script(HOOKS, 2)
            driver.execute_script(f"location.hash = '#/datasets/{info['id']}';")
            for _ in range(600):
                bench = driver.execute_script("return window.__bench;")
                if bench.get("drawn"):
                    break
                time.sleep(0.05)
            else:
                raise RuntimeError("the plots were not drawn within 30 s")
            drawn_pixels = driver.execute_script(CANVAS_DRAWN)
            if drawn_pixels == 0:
                raise RuntimeError("the plots' canvases are blank")
            a, r = bench["drawn"] - bench["arrived"], bench["drawn"] - bench["requested"]
            arrival_to_drawn.append(a)
            request_to_drawn.append(r)
            print(f"  run {run + 1}: data arrival to drawn {a:7.1f} ms, request to drawn {r:7.1f} ms "
                  f"({drawn_pixels} pixels drawn)")
        print(f"median of {args.runs}: data arrival to drawn {statistics.median(arrival_to_drawn):.1f} ms, "
              f"request to drawn {statistics.median(request_to_drawn):.1f} ms (target: under 1000 ms)")
    finally:
        if driver is not None:
            driver.quit()
        daemon.terminate()
        daemon.wait()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
