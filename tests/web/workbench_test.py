#!/usr/bin/python3
"""The web workbench in a real browser: headless Chromium driven by Selenium
against a real riccatid (--http-listen), as a user would use it.

  workbench_test.py --riccatid build/bin/riccatid --riccati build/bin/riccati \
      --models-dir build/lib/riccati/models --source-dir . [--screenshots docs/figures]

Signs in with a token (a wrong one refused), uploads the two-tank CSV, plots
its signals, runs an identification whose result table must hold the JSON
API's numbers (the API's own test holds them equal to gRPC's), checks that the
trace and overlay plots are drawn, validates the estimate, watches a session
fed by `riccati stream` (in parts the test waits on, as fast as riccatid takes
them: a slow host takes longer, it does not time out) and retunes its R
on-line, writes a text model in the Models page's editor (an error shown at
its line as one types; fixed, it is uploaded, listed with its units and opens
Identify), and shows a dataset named <script>alert(1)</script> as text. Also
what issue 31 found: intervals and tick labels that read the same, no truth on
the traces, a Validate page whose model was not its job's, a dataset that does
not fit refused only as a job, a retune form that showed nothing and demanded
every value, "Sign out" without a token, the favicon's 404. With
--screenshots, saves a PNG of every page there.

Each test starts signed out, signs in and makes the datasets and jobs it uses,
found by their ids: any one runs alone, in any order, sharing only the daemon
(`workbench_test.py ... Workbench.test_5_validate`, or `-k validate`).
"""
import argparse
import ctypes
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import unittest
import urllib.error
import urllib.request

from selenium import webdriver
from selenium.common.exceptions import NoAlertPresentException, StaleElementReferenceException, TimeoutException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions as EC
from selenium.webdriver.support.select import Select
from selenium.webdriver.support.ui import WebDriverWait

ARGS = None
TOKEN = "alpha-workbench-3e9d1c7b5a"
# The two-tank record's true parameters (tests/data/two_tank.json).
TRUTH = {"A1": 10, "A2": 5, "k1": 0.0791, "k2": 0.1342}
# How long a wait may take before the test fails: generous, for a loaded
# machine; the test never waits longer than what it waits for takes.
WAIT = 180

# Whether a canvas has anything drawn on it: pixels that are neither
# transparent nor the background's white.
CANVAS_DRAWN = """
const c = arguments[0];
const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
let drawn = 0;
for (let i = 0; i < d.length; i += 4) {
  if (d[i + 3] > 0 && (d[i] < 240 || d[i + 1] < 240 || d[i + 2] < 240)) drawn++;
}
return drawn;
"""


def die_with_parent():
    # riccatid ends with this test even when the test is killed (prctl PR_SET_PDEATHSIG).
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)


def read(path):
    with open(path) as f:
        return f.read()


def wait_for_file(path, process, what):
    for _ in range(WAIT * 10):
        if os.path.exists(path) and read(path).strip():
            return int(read(path).strip())
        if process.poll() is not None:
            raise RuntimeError(f"riccatid exited ({process.returncode}) before {what}")
        time.sleep(0.1)
    raise RuntimeError(f"riccatid did not write {what}")


class WorkbenchCase(unittest.TestCase):
    """A riccatid with a tokens file and a headless Chromium, for each test class; the helpers the tests share."""

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="riccati-web-")
        tokens = os.path.join(cls.dir, "tokens")
        line = subprocess.run([ARGS.riccatid, "--hash-token", "--tenant", "alpha"], input=TOKEN + "\n",
                              capture_output=True, text=True, check=True).stdout
        with open(tokens, "w") as f:
            f.write(line)
        os.chmod(tokens, 0o600)
        cls.token_file = os.path.join(cls.dir, "token")
        with open(cls.token_file, "w") as f:
            f.write(TOKEN + "\n")
        os.chmod(cls.token_file, 0o600)
        cls.log = open(os.path.join(cls.dir, "riccatid.log"), "w")
        cls.daemon = subprocess.Popen(
            [ARGS.riccatid, "--listen", "127.0.0.1:0", "--port-file", os.path.join(cls.dir, "port"),
             "--http-listen", "127.0.0.1:0", "--http-port-file", os.path.join(cls.dir, "http_port"),
             "--data-dir", os.path.join(cls.dir, "data"), "--models-dir", ARGS.models_dir,
             "--tokens-file", tokens, "--workers", "2"], stderr=cls.log, preexec_fn=die_with_parent)
        cls.addClassCleanup(cls.stop_daemon)
        cls.grpc_port = wait_for_file(os.path.join(cls.dir, "port"), cls.daemon, "its port")
        cls.http_port = wait_for_file(os.path.join(cls.dir, "http_port"), cls.daemon, "its HTTP port")
        cls.base = f"http://127.0.0.1:{cls.http_port}/"
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                    "--window-size=1400,1000", "--force-device-scale-factor=1"):
            options.add_argument(arg)
        cls.driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        cls.addClassCleanup(cls.driver.quit)
        cls.driver.set_script_timeout(60)

    @classmethod
    def stop_daemon(cls):
        cls.daemon.send_signal(signal.SIGTERM)
        code = cls.daemon.wait(timeout=60)
        cls.log.close()
        if code != 0:
            print(f"riccatid exited {code}:", read(os.path.join(cls.dir, "riccatid.log"))[-4000:], file=sys.stderr)
        shutil.rmtree(cls.dir, ignore_errors=True)

    # -- helpers -----------------------------------------------------------
    def api(self, path, body=None, method=None):
        request = urllib.request.Request(self.base + "api/v1" + path, method=method,
                                         data=None if body is None else json.dumps(body).encode(),
                                         headers={"Authorization": "Bearer " + TOKEN,
                                                  "Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=60) as response:
            return json.loads(response.read() or b"{}")

    def wait(self, condition, timeout=WAIT):
        # A table redrawn while the condition reads it leaves stale elements:
        # the condition is tried again.
        return WebDriverWait(self.driver, timeout,
                             ignored_exceptions=[StaleElementReferenceException]).until(condition)

    def find(self, css):
        return self.wait(EC.presence_of_element_located((By.CSS_SELECTOR, css)))

    def go(self, route):
        self.driver.get(self.base + "#/" + route)

    def shot(self, name):
        if not ARGS.screenshots:
            return
        os.makedirs(ARGS.screenshots, exist_ok=True)
        # The whole page, not only the window: a viewport as tall as what it shows.
        height = self.driver.execute_script("return document.documentElement.scrollHeight")
        self.driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
            "width": 1400, "height": max(900, min(height, 5000)), "deviceScaleFactor": 1, "mobile": False})
        time.sleep(0.3)  # the page lays out again; screenshots only, never an assertion
        self.driver.save_screenshot(os.path.join(ARGS.screenshots, f"workbench-{name}.png"))
        self.driver.execute_cdp_cmd("Emulation.clearDeviceMetricsOverride", {})

    def assert_plots_drawn(self, container_css, at_least=1):
        canvases = self.wait(lambda d: (lambda c: c if len(c) >= at_least else False)(
            d.find_elements(By.CSS_SELECTOR, container_css + " canvas")))
        for canvas in canvases:
            self.assertGreater(self.driver.execute_script(CANVAS_DRAWN, canvas), 100,
                               f"a plot in {container_css} is blank")
        return canvases

    # Each plot's y-axis tick labels, range and the series' finite values.
    PLOTS = """
        return [...document.querySelectorAll(arguments[0] + ' .plot')].map((box) => {
          const u = box.uplot;
          return {title: box.dataset.title, ticks: u.axes[1]._values || [], min: u.scales.y.min, max: u.scales.y.max,
                  labels: u.series.slice(1).map((s) => s.label),
                  data: u.data.slice(1).map((d) => Array.from(d).filter((v) => v !== null && Number.isFinite(v)))};
        });"""

    def plots(self, container_css):
        return self.driver.execute_script(self.PLOTS, container_css)

    def assert_ticks_distinct(self, container_css):
        plots = self.plots(container_css)
        self.assertTrue(plots, f"no plots in {container_css}")
        for p in plots:
            self.assertGreaterEqual(len(p["ticks"]), 2, p)
            self.assertEqual(len(set(p["ticks"])), len(p["ticks"]), f"{p['title']}: tick labels repeat: {p['ticks']}")
        return plots

    def upload_raw(self, path, name, inputs, outputs):
        with open(path, "rb") as f:
            body = f.read()
        request = urllib.request.Request(
            self.base + f"api/v1/datasets?name={name}&input_columns={','.join(inputs)}&output_columns={','.join(outputs)}",
            data=body, method="POST", headers={"Authorization": "Bearer " + TOKEN, "Content-Type": "text/csv"})
        with urllib.request.urlopen(request, timeout=60) as response:
            return json.loads(response.read())["id"]

    def wait_job(self, terminal_state="SUCCEEDED"):
        state = self.find("#job-state")
        self.wait(lambda d: state.text in ("SUCCEEDED", "FAILED", "CANCELLED"))
        self.assertEqual(state.text, terminal_state, self.driver.find_element(By.ID, "main").text[:2000])
        return self.driver.current_url.split("#/jobs/")[1]

    def upload(self, path, name, truth=""):
        self.go("datasets")
        file_input = self.find("#upload-file")
        file_input.send_keys(path)
        Select(self.find("#upload-model")).select_by_value("two_tank")
        field = self.find("#upload-name")
        field.clear()
        field.send_keys(name)
        if truth:
            self.find("#upload-truth").send_keys(truth)
        before = {d["id"] for d in self.api("/datasets").get("datasets", [])}
        self.find("#upload-button").click()
        self.wait(lambda d: "Stored" in d.find_element(By.ID, "upload-status").text
                  or "error" in d.find_element(By.ID, "upload-status").get_attribute("innerHTML"))
        self.assertIn("Stored", self.driver.find_element(By.ID, "upload-status").text)
        # This upload's row: the one dataset the tenant did not have before (a name another
        # upload has too is another row); the page lists it once it has read the list again.
        added = [d["id"] for d in self.api("/datasets").get("datasets", []) if d["id"] not in before]
        self.assertEqual(len(added), 1, added)
        row = self.find(f'#datasets tbody tr[data-id="{added[0]}"]')
        self.assertEqual(row.find_element(By.CSS_SELECTOR, "td.name").text, name)
        return added[0]

    def fill_settings(self, settings):
        """Fills the Identify form as the CLI's flags would be given: [(flag, value), ...], value None for a
        switch or a names flag given alone; a repeated flag's values joined by commas, as the field takes them."""
        joined = {}
        for flag, value in settings:
            joined[flag] = value if flag not in joined else f"{joined[flag]}, {value}"
        for flag, value in joined.items():
            if flag == "--experiment":
                for dataset in value.split(", "):
                    self.find("#experiment-add").click()
                    added = self.driver.find_elements(By.CSS_SELECTOR, "#experiments select")[-1]
                    Select(added).select_by_value(dataset)
                continue
            if flag in ("--exclude", "--output-limit"):
                self.find("#" + flag[2:]).send_keys(value)
                continue
            control = self.find(f'.settings-form [data-flag="{flag}"]:not(.setting)')
            if control.tag_name == "select":
                Select(control).select_by_value(value)
            elif value is None:  # a switch, or a names flag alone: its implicit value
                box = control if control.get_attribute("type") == "checkbox" else \
                    self.driver.find_element(By.ID, control.get_attribute("id") + "-implicit")
                box.click()
            else:
                control.clear()
                control.send_keys(value)

    def sign_in(self):
        self.driver.get(self.base)
        self.find("#token").send_keys(TOKEN)
        self.find("#signin-button").click()
        self.find("#signout")


class Workbench(WorkbenchCase):
    def setUp(self):
        # Nothing carries from one test to the next but the daemon: each
        # starts signed out (the token and the model editor's draft are in
        # the page's storage), and makes the datasets and jobs it uses.
        self.driver.get(self.base)
        self.driver.execute_script("sessionStorage.clear(); localStorage.clear();")
        self.driver.refresh()
        self.find("#token")

    # -- helpers of these tests --------------------------------------------
    def upload_two_tank(self, name):
        """The two-tank record from the Datasets page, with the parameters it
        was simulated with (tests/data/two_tank.json); returns its id."""
        return self.upload(os.path.join(ARGS.source_dir, "tests/data/two_tank.csv"), name,
                           truth="A1:10, A2:5, k1:0.0791, k2:0.1342")

    def identify(self, dataset, shot=False):
        """Hensen's settings (examples/two_tank_hensen.yaml), three passes, from the
        Identify page on `dataset`; returns the job's id once it succeeded."""
        self.go(f"identify?dataset={dataset}&model=two_tank")
        self.find('[data-flag="--theta0"]')
        if shot:
            self.shot("identify")
        self.fill_settings([("--passes", "3"), ("--theta0", "20,20,1,1"), ("--p0", "0,0,10,10,10,10"),
                            ("--r", "1e-3"), ("--substeps", "10")])
        self.find("#identify-submit").click()
        return self.wait_job()

    def wait_api_job(self, job):
        """Waits for a job submitted through the API to end; it must have succeeded."""
        def ended(_):
            state = self.api("/jobs/" + job)["state"]
            return state if state in ("JOB_STATE_SUCCEEDED", "JOB_STATE_FAILED", "JOB_STATE_CANCELLED") else False
        self.assertEqual(self.wait(ended), "JOB_STATE_SUCCEEDED", self.api("/jobs/" + job).get("error"))

    def stream_rows(self, rows, *args):
        """`riccati stream` as a rig: the first `rows` rows of the two-tank record
        (when resuming a session, those after its t), as fast as riccatid takes
        them, the session kept open at the end. Ended with the test, should it
        fail first."""
        part = os.path.join(self.dir, f"two_tank_{rows}.csv")
        with open(os.path.join(ARGS.source_dir, "tests/data/two_tank.csv")) as f, open(part, "w") as out:
            out.writelines(line for _, line in zip(range(rows + 1), f))  # the header, then `rows` rows
        process = subprocess.Popen(
            [ARGS.riccati, "--server", f"127.0.0.1:{self.grpc_port}", "--token-file", self.token_file,
             "stream", "--data", part, "--rate", "0", "--keep", "--live", "never", *args],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

        def end():
            if process.poll() is None:
                process.terminate()
            process.communicate()
        self.addCleanup(end)
        return process

    def finished(self, process):
        """Waits for a `riccati stream` to end; it must have succeeded. Its standard error."""
        _, err = process.communicate(timeout=WAIT)
        self.assertEqual(process.returncode, 0, err)
        return err

    def measurements_shown(self):
        summary = self.driver.find_element(By.ID, "session-summary").text
        return int(summary.split(" · ")[1].split()[0]) if " measurements" in summary else -1

    # -- the tests, in the order a user goes (each runs alone too) -------------
    def test_1_sign_in(self):
        self.driver.get(self.base)
        token = self.find("#token")
        token.send_keys("not-the-token")
        self.find("#signin-button").click()
        self.wait(lambda d: d.find_element(By.ID, "signin-error").text != "")
        self.assertIn("not valid", self.driver.find_element(By.ID, "signin-error").text)
        self.shot("signin")
        token = self.find("#token")
        token.clear()
        token.send_keys(TOKEN)
        self.find("#signin-button").click()
        self.find("#signout")
        # A favicon in the page itself: no request for /favicon.ico, no 404.
        icon = self.driver.execute_script("return document.querySelector('link[rel=icon]').href")
        self.assertTrue(icon.startswith("data:image/svg+xml"), icon)
        self.assertEqual([a.text for a in self.driver.find_elements(By.CSS_SELECTOR, "#nav a")],
                         ["Datasets", "Identify", "Validate", "Sessions", "Models", "Jobs"])

    def test_2_upload_and_plot(self):
        self.sign_in()
        # With the parameters it was simulated with (tests/data/two_tank.json).
        dataset = self.upload_two_tank("two_tank.csv")
        info = self.api("/datasets/" + dataset)
        self.assertEqual(int(info["samples"]), 2000)
        self.assertEqual(info["inputNames"], ["F1", "F2"])
        self.assertEqual(info["outputNames"], ["h1", "h2"])
        self.assertEqual(info["trueParameters"], TRUTH)
        self.shot("datasets")
        self.go("datasets/" + dataset)
        self.assertEqual(self.find("#dataset-name").text, "two_tank.csv")
        self.assertEqual(self.find("#dataset-truth").text,
                         "True parameters: A1 = 10, A2 = 5, k1 = 0.0791, k2 = 0.1342")
        self.assert_plots_drawn("#signal-plots", 4)
        self.shot("dataset")

    def test_3_a_name_is_text(self):
        self.sign_in()
        csv = os.path.join(ARGS.source_dir, "tests/data/two_tank.csv")
        name = "<script>alert(1)</script>"
        dataset = self.upload(csv, name)
        cell = self.driver.find_element(By.CSS_SELECTOR, f'#datasets tr[data-id="{dataset}"] td.name')
        self.assertEqual(cell.text, name)
        self.assertEqual(self.driver.find_elements(By.CSS_SELECTOR, "#main script"), [])
        with self.assertRaises(NoAlertPresentException):
            self.driver.switch_to.alert.text
        self.go("datasets/" + dataset)
        self.assertEqual(self.find("#dataset-name").text, name)
        with self.assertRaises(NoAlertPresentException):
            self.driver.switch_to.alert.text
        self.api("/datasets/" + dataset, method="DELETE")

    def test_4_identify(self):
        self.sign_in()
        # Hensen's settings (examples/two_tank_hensen.yaml), three passes, on a
        # dataset that declares its truth.
        job = self.identify(self.upload_two_tank("identify.csv"), shot=True)
        table = self.find("#result-table")
        result = self.api(f"/jobs/{job}/result")["identification"]
        names = result["paramNames"]
        self.assertEqual(names, ["A1", "A2", "k1", "k2"])
        for i, name in enumerate(names):
            row = table.find_element(By.CSS_SELECTOR, f'tr[data-param="{name}"]')
            estimate = row.find_element(By.CSS_SELECTOR, 'td[data-col="Estimate"]')
            std = row.find_element(By.CSS_SELECTOR, 'td[data-col="Std error"]')
            self.assertEqual(float(estimate.get_attribute("data-value")), result["thetaMean"][i])
            self.assertEqual(float(std.get_attribute("data-value")), result["thetaStd"][i])
            self.assertEqual(row.find_element(By.CSS_SELECTOR, "td.unit").text, ["m^2", "m^2", "m^2.5/s", "m^2.5/s"][i])
            # What is shown: the same number to five significant digits.
            self.assertAlmostEqual(float(estimate.text) / result["thetaMean"][i], 1.0, places=4)
            # The truth the dataset declares, and the error in standard errors.
            truth = row.find_element(By.CSS_SELECTOR, 'td[data-col="Truth"]')
            self.assertEqual(float(truth.get_attribute("data-value")), TRUTH[name])
            sigmas = row.find_element(By.CSS_SELECTOR, 'td[data-col="Error (σ)"]')
            self.assertAlmostEqual(float(sigmas.get_attribute("data-value")),
                                   (result["thetaMean"][i] - TRUTH[name]) / result["thetaStd"][i], places=9)
            # riccatid's interval (output error's at the estimate, widened to hold
            # it), with the digits that tell its ends apart; the filter's own std beside.
            interval = row.find_element(By.CSS_SELECTOR, 'td[data-col="95 % interval"]').text
            lo, hi = (float(v) for v in interval.split(" … "))
            self.assertLess(lo, hi, interval)
            width = result["ciUpper"][i] - result["ciLower"][i]
            self.assertAlmostEqual((hi - lo) / width, 1.0, delta=0.1, msg=interval)
            self.assertAlmostEqual((lo - result["ciLower"][i]) / width, 0.0, delta=0.05, msg=interval)
            filter_std = row.find_element(By.CSS_SELECTOR, 'td[data-col="Filter std"]')
            self.assertEqual(float(filter_std.get_attribute("data-value")), result["filterThetaStd"][i])
        self.assertIn("output error at the estimate", self.find("#covariance-method").text)
        # Its warnings (not settled, residuals not white), each a paragraph of its own words.
        shown = [p.text for p in self.driver.find_elements(By.CSS_SELECTOR, "#main p.warn")]
        self.assertEqual(shown, result["warnings"])
        self.assertNotIn("[object", self.find("#main").text)
        # Hensen's estimates near the truth (two_tank.json: 10, 5, 0.0791, 0.1342).
        self.assertAlmostEqual(result["thetaMean"][0], 10, delta=1)
        self.find("#correlation")
        self.assert_plots_drawn("#traces", 4)
        self.assert_plots_drawn("#overlay", 2)
        # Traces: the truth dashed (from the dataset); the axes span the passes after the
        # first (its start from theta0 would flatten them) and the truth; the ticks differ.
        self.assertEqual(self.find("#truth-input").get_attribute("value"), "A1=10, A2=5, k1=0.0791, k2=0.1342")

        def assert_axes_span(first):
            for p in self.assert_ticks_distinct("#traces"):
                self.assertEqual(p["labels"], ["pass 1", "pass 2", "pass 3", "truth"], p["title"])
                self.assertEqual(p["data"][-1][0], TRUTH[p["title"]])
                values = [v for series in p["data"][first:] for v in series]
                self.assertLessEqual(p["min"], min(values), p["title"])
                self.assertGreaterEqual(p["max"], max(values), p["title"])
                # Not much wider than that: the last passes are not a flat line.
                self.assertLess(p["max"] - p["min"], 1.2 * (max(values) - min(values)), p["title"])
        assert_axes_span(1)
        self.assert_ticks_distinct("#overlay")
        self.shot("identify-result")
        self.find("#traces-every-pass").click()
        self.wait(lambda d: self.plots("#traces")[2]["max"] > 0.5)  # k1's first pass starts at 1
        assert_axes_span(0)
        self.find("#traces-every-pass").click()
        # A truth the user types replaces the dataset's.
        field = self.find("#truth-input")
        field.clear()
        field.send_keys("A1=11\n")
        self.wait(lambda d: [p["labels"][-1] for p in self.plots("#traces")] == ["truth", "pass 3", "pass 3", "pass 3"])
        self.assertEqual(self.plots("#traces")[0]["data"][-1][0], 11)

    def test_4b_a_dataset_that_does_not_fit_is_refused_before_the_job(self):
        self.sign_in()
        # One output where two_tank has two: refused at submit, the columns named; no job made.
        dataset = self.upload_raw(os.path.join(ARGS.source_dir, "tests/data/two_tank.csv"), "one_output.csv",
                                  ["F1", "F2"], ["h2"])
        jobs_before = len(self.api("/jobs").get("jobs", []))
        self.go(f"identify?dataset={dataset}&model=two_tank")
        # The page sees it from the columns, before anything is sent...
        note = self.wait(lambda d: d.find_element(By.CSS_SELECTOR, "#identify-columns .error"))
        self.assertIn("model two_tank has 2 outputs (h1, h2), dataset one_output.csv has 1 (h2)", note.text)
        self.assertFalse(self.find("#identify-submit").is_enabled())
        # ...and riccatid refuses the same request at submit.
        with self.assertRaises(urllib.error.HTTPError) as e:
            self.api("/jobs/identification",
                     {"model": "two_tank", "datasetId": dataset, "filter": {"r": {"scalar": 1e-3}}})
        self.assertIn(f"experiment 1 ({dataset}): model two_tank has 2 outputs (h1, h2), the dataset has 1 (h2)",
                      json.loads(e.exception.read())["message"])
        self.assertEqual(len(self.api("/jobs").get("jobs", [])), jobs_before)
        self.api("/datasets/" + dataset, method="DELETE")

    def test_4b_estimation_diagnostics(self):
        self.sign_in()
        # Output error on the noisy record, from the truth: the residual tests a
        # table each, rows by the model's names, p-values and dof as the API sends them.
        noisy = self.upload(os.path.join(ARGS.source_dir, "tests", "data", "two_tank_noisy.csv"), "two_tank_noisy.csv")
        self.go(f"identify?dataset={noisy}&model=two_tank")
        self.find('[data-flag="--method"]')
        self.fill_settings([("--method", "oe"), ("--theta0", "10,5,0.0791,0.1342")])
        self.find("#identify-submit").click()
        job = self.wait_job()
        estimation = self.api(f"/jobs/{job}/result")["estimation"]
        d = estimation["experiments"][0]["diagnostics"]
        # The likelihood and the criteria, as the API has them: k the four
        # parameters and sigma^2, n both outputs' 2000 samples.
        criteria = self.find("#criteria").text
        self.assertEqual((estimation["estimatedQuantities"], int(estimation["samples"])), (5, 4000))
        self.assertIn("(k = 5 estimated, n = 4000;", criteria)
        shown = {m.group(1): float(m.group(2)) for m in re.finditer(r"\b(Log-likelihood|AIC|AICc|BIC) ([-0-9.e+]+)", criteria)}
        for label, field in (("Log-likelihood", "logLikelihood"), ("AIC", "aic"), ("AICc", "aicc"), ("BIC", "bic")):
            self.assertAlmostEqual(shown[label], float(estimation[field]), delta=1e-9 * abs(float(estimation[field])))
        white = self.find("#diag-whiteness")
        rows = white.find_elements(By.CSS_SELECTOR, "tbody tr")
        self.assertEqual([r.get_attribute("data-output") for r in rows], ["h1", "h2"])
        for i, r in enumerate(rows):
            cells = [c.text for c in r.find_elements(By.CSS_SELECTOR, "th, td")]
            self.assertEqual(cells[0], ["h1", "h2"][i])
            self.assertAlmostEqual(float(cells[3]), float(d["ljungBoxP"][i]), delta=abs(float(d["ljungBoxP"][i])) * 1e-2)
            self.assertEqual(cells[4], str(d["ljungBoxDof"]))
            self.assertIn(cells[5], ("pass", "fail"))
        pairs = self.find("#diag-inputs").find_elements(By.CSS_SELECTOR, "tbody tr")
        self.assertEqual([(r.get_attribute("data-output"), r.get_attribute("data-input")) for r in pairs],
                         [("h1", "F1"), ("h1", "F2"), ("h2", "F1"), ("h2", "F2")])
        self.assertNotIn("output 1", self.find("#diagnostics").text)
        # A table that wraps within the page, not a line running off it.
        page = self.driver.execute_script("return document.documentElement.clientWidth")
        for table in self.driver.find_elements(By.CSS_SELECTOR, "#diagnostics table"):
            self.assertLessEqual(table.rect["x"] + table.rect["width"], page)
        self.shot("estimation-result")
        if ARGS.screenshots:
            self.find("#diagnostics").screenshot(os.path.join(ARGS.screenshots, "workbench-diagnostics.png"))

    def test_5_validate(self):
        self.sign_in()
        identified = self.identify(self.upload_two_tank("validate.csv"))
        # Opened bare, the model is the chosen job's (its estimate fits it), not the first model listed.
        # The job chosen is the first succeeded identification riccatid lists: this test's own when it
        # runs alone, an earlier test's (of two_tank as well) when it runs after them.
        listed = [j for j in self.api("/jobs").get("jobs", [])
                  if j.get("identification") and j["state"] == "JOB_STATE_SUCCEEDED"]
        self.assertIn(identified, [j["id"] for j in listed])
        self.go("validate")
        source = Select(self.find("#validate-source"))
        model = Select(self.find("#validate-model"))
        self.assertEqual(source.first_selected_option.get_attribute("value"), listed[0]["id"])
        self.assertEqual(model.first_selected_option.get_attribute("value"), listed[0]["identification"]["model"])
        self.assertEqual(model.first_selected_option.get_attribute("value"), "two_tank")
        self.assertFalse(self.find("#validate-theta").is_displayed())
        self.assertTrue(self.find("#validate-horizon").is_displayed())  # a job's estimate: K steps ahead too
        # Another model: its own parameters, typed in (no horizon: no job's filter); the job again: its model again.
        model.select_by_value("flexible_manipulator")
        self.assertEqual(source.first_selected_option.get_attribute("value"), "")
        self.assertTrue(self.find("#validate-theta").is_displayed())
        self.assertFalse(self.find("#validate-horizon").is_displayed())
        source.select_by_value(identified)
        self.assertEqual(model.first_selected_option.get_attribute("value"), "two_tank")
        self.go(f"jobs/{identified}")
        self.find("#validate-link").click()
        source = Select(self.find("#validate-source"))
        self.assertEqual(source.first_selected_option.get_attribute("value"), identified)
        self.shot("validate")
        self.find("#validate-submit").click()
        job = self.wait_job()
        fits = self.api(f"/jobs/{job}/result")["validation"]["fits"]
        cells = self.wait(lambda d: d.find_elements(By.CSS_SELECTOR, "#fits td.fit"))
        self.assertEqual([float(c.get_attribute("data-value")) for c in cells], [f["fitPercent"] for f in fits])
        self.assertGreater(fits[0]["fitPercent"], 90)
        self.assert_plots_drawn("#overlay", 2)
        self.shot("validate-result")
        # Three samples ahead: the job's filter predicts; the result says so.
        self.go(f"jobs/{identified}")
        self.find("#validate-link").click()
        self.find("#validate-horizon").send_keys("3")
        self.find("#validate-submit").click()
        ahead = self.wait_job()
        self.assertNotEqual(ahead, job)
        result = self.api(f"/jobs/{ahead}/result")["validation"]
        self.assertEqual(result["horizon"], 3)
        self.assertIn("3 samples ahead", result["predictor"])

    def test_6_jobs_and_models(self):
        self.sign_in()
        # Two jobs of its own, made through the API: an identification (one pass on the first
        # 200 samples) and a validation at the truth.
        dataset = self.upload_raw(os.path.join(ARGS.source_dir, "tests/data/two_tank.csv"), "jobs.csv",
                                  ["F1", "F2"], ["h1", "h2"])
        jobs = [self.api("/jobs/identification", {"model": "two_tank", "datasetId": dataset, "theta0": [20, 20, 1, 1],
                                                  "passes": 1, "endSample": 200, "filter": {"r": {"scalar": 1e-3}}})["id"],
                self.api("/jobs/validation", {"model": "two_tank", "datasetId": dataset,
                                              "theta": {"values": list(TRUTH.values())},
                                              "initialState": {"firstMeasurement": True}})["id"]]
        for job in jobs:
            self.wait_api_job(job)
        self.go("jobs")
        rows = self.wait(lambda d: (lambda r: r if set(jobs) <= {e.get_attribute("data-id") for e in r} else False)(
            d.find_elements(By.CSS_SELECTOR, "#jobs tbody tr")))
        self.assertGreaterEqual(len(rows), 2)
        for job in jobs:
            self.assertIn(job, [r.get_attribute("data-id") for r in rows])
        self.shot("jobs")
        self.go("models")
        self.find('#model-list section[data-model="two_tank"]')
        # Units as the plugin declares them.
        unit = self.find('section[data-model="two_tank"] tr[data-param="k1"] td.unit')
        self.assertEqual(unit.text, "m^2.5/s")

    def test_6c_compare_fits(self):
        self.sign_in()
        # Two output-error fits of the noisy record, k2 free and held: ticked in the
        # list, compared as riccatid compares them (POST /api/v1/jobs/compare).
        dataset = self.upload_raw(os.path.join(ARGS.source_dir, "tests/data/two_tank_noisy.csv"), "compare.csv",
                                  ["F1", "F2"], ["h1", "h2"])
        clean = self.upload_raw(os.path.join(ARGS.source_dir, "tests/data/two_tank.csv"), "compare-clean.csv",
                                ["F1", "F2"], ["h1", "h2"])
        spec = {"model": "two_tank", "datasetId": dataset, "method": "IDENTIFICATION_METHOD_OE",
                "theta0": [11, 6, 0.09, 0.15]}
        free = self.api("/jobs/identification", spec)["id"]
        held = self.api("/jobs/identification", dict(spec, fixed=[{"name": "k2", "value": 0.12}]))["id"]
        for job in (free, held):
            self.wait_api_job(job)
        self.go("jobs")
        for job in (free, held):
            self.find(f'#jobs tr[data-id="{job}"] input.pick').click()
        self.find("#compare-jobs").click()
        table = self.find("#comparison")
        expected = self.api("/jobs/compare", {"jobIds": [free, held]})
        rows = table.find_elements(By.CSS_SELECTOR, "tbody tr")
        self.assertEqual([r.get_attribute("data-id") for r in rows], [free, held])
        self.assertEqual([j["jobId"] for j in expected["jobs"]], [free, held])
        best = table.find_element(By.CSS_SELECTOR, "td.aic.best")
        self.assertIn(free, best.find_element(By.XPATH, "..").get_attribute("data-id"))
        test = self.find(f'#ratio-tests li[data-smaller="{held}"][data-larger="{free}"]')
        self.assertIn("the larger model fits significantly better", test.text)
        self.assertTrue(expected["tests"][0]["significant"])
        # Both fits on a common record (the noise-free one, uploaded above): each
        # validated there, its fits beside the others, as riccatid's validations say.
        Select(self.find("#compare-dataset")).select_by_value(clean)
        self.find("#compare-validate").click()
        cell = self.find(f'#comparison tr[data-id="{free}"] td.validation[data-output="h2"]')
        validations = dict(kv.split("=", 1) for kv in self.driver.current_url.split("?", 1)[1].split("&"))["validations"]
        again = self.api("/jobs/compare", {"jobIds": [free, held], "validationJobIds": validations.split(",")})
        self.assertEqual(again["validationDatasetId"], clean)
        by_job = {j["jobId"]: j for j in again["jobs"]}
        fit = {f["name"]: f["fitPercent"] for f in by_job[free]["validationFits"]}
        self.assertAlmostEqual(float(cell.text), fit["h2"], places=2)
        held_fit = {f["name"]: f["fitPercent"] for f in by_job[held]["validationFits"]}
        self.assertGreater(fit["h2"], held_fit["h2"])  # the true model fits the clean record better
        self.assertIn("simulated on compare-clean.csv", self.find("#comparison").find_element(By.XPATH, "..").text)
        self.shot("compare")

    def test_6b_write_a_model(self):
        self.sign_in()
        self.go("models")
        source = self.find("#model-source")
        # A model with an error on line 4: the error is shown at its line as one types.
        source.clear()
        source.send_keys("model: wb_tank\nstates: [x]\nder:\n  x: (x +) * 2\noutputs: {y: x}\n")
        line = self.wait(lambda d: (lambda e: e if e and "Line 4" in e[0].text else False)(
            d.find_elements(By.ID, "model-error-line")))[0]
        self.assertEqual(line.text, "Line 4, column 10:")
        self.assertEqual([s.text for s in self.driver.find_elements(By.CSS_SELECTOR, "#model-gutter span.bad")], ["4"])
        self.assertIn("unexpected ')'", self.find("#model-error").text)
        self.assertFalse(self.find("#model-upload").is_enabled())
        self.shot("models-editor-error")
        # Fixed: it checks, uploads, is listed with its units, and Identify opens with it.
        source.clear()
        source.send_keys("model: wb_tank\nstates: {h: {unit: m}}\ninputs: {F: {unit: m^3/s}}\nparameters:\n"
                         "  A: {value: 10, min: 0, unit: m^2}\n  k: {value: 0.08, min: 0, unit: m^2.5/s}\n"
                         "der:\n  h: (F - k * sqrt(max(h, 0))) / A\noutputs:\n  h: h\n")
        self.wait(lambda d: "✓ wb_tank" in d.find_element(By.ID, "model-check").text)
        self.assertEqual(self.driver.find_elements(By.CSS_SELECTOR, "#model-gutter span.bad"), [])
        self.wait(lambda d: d.find_element(By.ID, "model-upload").is_enabled())
        self.find("#model-upload").click()
        self.wait(lambda d: "Stored wb_tank@1" in d.find_element(By.ID, "model-stored").text)
        unit = self.find('#model-list section[data-model="wb_tank"] tr[data-param="A"] td.unit')
        self.assertEqual(unit.text, "m^2")
        self.assertEqual([m["name"] for m in self.api("/models")["models"] if m["name"] == "wb_tank"], ["wb_tank"])
        self.shot("models")
        self.find("#model-identify").click()
        self.wait(lambda d: Select(d.find_element(By.ID, "model")).first_selected_option.get_attribute("value")
                  == "wb_tank")
        self.assertEqual(self.find('#parameters tr[data-param="A"] th').text, "A [m^2]")
        self.assertIn("#/identify?model=wb_tank", self.driver.current_url)

    def test_7_session_live(self):
        # A rig: `riccati stream` replays the record into a session in parts the
        # test waits on, never against the clock (a slow host takes longer, it
        # does not time out). Its first 100 rows make the session, kept open
        # between parts.
        self.sign_in()
        err = self.finished(self.stream_rows(
            100, "--config", os.path.join(ARGS.source_dir, "examples/two_tank_hensen.yaml")))
        session = [line.split()[1] for line in err.splitlines() if line.startswith("session ")][0]
        self.go("sessions")
        link = self.wait(lambda d: [a for a in d.find_elements(By.CSS_SELECTOR, "#sessions tbody tr td a")
                                    if a.text == session])[0]
        self.shot("sessions")
        link.click()
        self.find("#session-summary")
        # Estimates update as they come: the count of measurements shown
        # follows each part streamed while the page is open, twice.
        self.wait(lambda d: self.measurements_shown() == 100)
        counts = [self.measurements_shown()]
        for rows in (300, 500):
            streaming = self.stream_rows(rows, "--session", session)
            self.wait(lambda d: self.measurements_shown() == rows)
            counts.append(self.measurements_shown())
            self.finished(streaming)
        self.assertEqual(counts, [100, 300, 500])
        self.assertEqual(counts, sorted(set(counts)))
        self.assert_plots_drawn("#session-plots", 6)

        # Retune on-line: R 1000 times larger. The filter leans on the model
        # now, so the uncertainty of h1 (its ±2σ) grows. The session is idle
        # between parts: the retuning falls after measurement 500 on any host,
        # and what is compared is the same each run (0.0039 at 500, 0.0067 at
        # 1000, on 2026-11-28).
        def two_sigma(name):  # read at once: the table is redrawn at every estimate
            return self.driver.execute_script("""
                for (const tr of document.querySelectorAll('#session-values tbody tr')) {
                  if (tr.querySelector('th').textContent === arguments[0]) return Number(tr.querySelectorAll('td')[1].textContent);
                }
                return null;""", name)
        before = two_sigma("h1")
        self.assertIsNotNone(before)
        # The fields show what the filter runs with (examples/two_tank_hensen.yaml: R = 1e-3 I, Q = 0).
        self.assertEqual([self.find(f"#retune-r-{o}").get_attribute("value") for o in ("h1", "h2")], ["0.001", "0.001"])
        self.assertEqual(self.find("#retune-q-A1").get_attribute("value"), "0")
        # Applying with nothing changed sends nothing.
        self.find("#retune-apply").click()
        self.wait(lambda d: "Nothing changed" in d.find_element(By.ID, "retune-status").text)
        # One value changed: R goes with the other output's as it was, Q is not sent.
        field = self.find("#retune-r-h1")
        field.clear()
        field.send_keys("1")
        self.find("#retune-apply").click()
        self.wait(lambda d: "Retuned" in d.find_element(By.ID, "retune-status").text)
        self.assertIn("Retuned R at", self.driver.find_element(By.ID, "retune-status").text)
        self.find("#retunings table tbody tr")
        self.assertEqual(self.driver.current_url.split("#/sessions/")[1], session)
        info = self.api("/sessions/" + session)
        self.assertEqual(len(info["retunings"]), 1)
        self.assertEqual(info["retunings"][0]["r"]["diagonal"]["values"], [1, 0.001])
        self.assertNotIn("q", info["retunings"][0])
        self.assertEqual(info["r"]["diagonal"]["values"], [1, 0.001])
        self.assertEqual(self.find("#retune-r-h1").get_attribute("value"), "1")
        # The filter retuned, the rig goes on: 500 rows more, all of them shown.
        streaming = self.stream_rows(1000, "--session", session)
        self.wait(lambda d: self.measurements_shown() == 1000)
        self.finished(streaming)
        seen = []
        try:
            self.wait(lambda d: seen.append(two_sigma("h1")) or (seen[-1] or 0) > 1.5 * before)
        except TimeoutException:
            self.fail(f"the ±2σ of h1 did not grow after R was raised: {before} before, then {seen[-20:]}")
        self.assert_ticks_distinct("#session-plots")
        self.shot("session")

    def test_8_no_sign_out_without_a_token(self):
        # A riccatid without a tokens file lets loopback in: nothing to sign out of.
        data = os.path.join(self.dir, "open")
        port_file = os.path.join(self.dir, "open_http_port")
        daemon = subprocess.Popen(
            [ARGS.riccatid, "--listen", "127.0.0.1:0", "--port-file", os.path.join(self.dir, "open_port"),
             "--http-listen", "127.0.0.1:0", "--http-port-file", port_file, "--data-dir", data,
             "--models-dir", ARGS.models_dir], stderr=subprocess.DEVNULL, preexec_fn=die_with_parent)
        try:
            port = wait_for_file(port_file, daemon, "its HTTP port")
            self.driver.execute_script("sessionStorage.clear()")
            self.driver.get(f"http://127.0.0.1:{port}/#/models")
            self.find("#no-token")
            self.assertEqual(self.driver.find_elements(By.ID, "signout"), [])
            self.assertEqual(len(self.driver.find_elements(By.CSS_SELECTOR, "#nav a")), 6)
        finally:
            daemon.send_signal(signal.SIGTERM)
            self.assertEqual(daemon.wait(timeout=60), 0)


def main_args():
    """The options of the web tests (this file's and forms_test.py's); the rest are unittest's."""
    global ARGS, REST
    parser = argparse.ArgumentParser()
    parser.add_argument("--riccatid", required=True)
    parser.add_argument("--riccati", required=True)
    parser.add_argument("--models-dir", required=True)
    parser.add_argument("--source-dir", required=True)
    parser.add_argument("--screenshots", default="")
    ARGS, REST = parser.parse_known_args()


REST = []


def main():
    main_args()
    unittest.main(argv=[sys.argv[0]] + REST, verbosity=2)


if __name__ == "__main__":
    main()
