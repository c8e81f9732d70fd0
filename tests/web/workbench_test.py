#!/usr/bin/python3
"""The web workbench in a real browser: headless Chromium driven by Selenium
against a real riccatid (--http-listen), as a user would use it.

  workbench_test.py --riccatid build/bin/riccatid --riccati build/bin/riccati \
      --models-dir build/lib/riccati/models --source-dir . [--screenshots docs/figures]

Signs in with a token (a wrong one refused), uploads the two-tank CSV, plots
its signals, runs an identification whose result table must hold the JSON
API's numbers (the API's own test holds them equal to gRPC's), checks that the
trace and overlay plots are drawn, validates the estimate, watches a session
fed by `riccati stream` (in parts the test waits on, so a slow host takes
longer rather than timing out) and retunes its R on-line, writes a text model in the
Models page's editor (an error shown at its line as one types; fixed, it is
uploaded, listed with its units and opens Identify), and shows a dataset named
<script>alert(1)</script> as text. With --screenshots, saves a PNG of every page there.
Each test signs in and makes the datasets and jobs it uses: they run alone
or in any order, sharing only the daemon.
"""
import argparse
import ctypes
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import unittest
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


class Workbench(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="riccati-web-")
        cls.stream = None
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
        if cls.stream is not None and cls.stream.poll() is None:
            cls.stream.terminate()
            cls.stream.wait()
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

    def setUp(self):
        # Nothing carries from one test to the next but the daemon: each
        # starts signed out, and makes the datasets and jobs it uses.
        self.driver.get(self.base)
        self.driver.execute_script("sessionStorage.clear(); localStorage.clear();")

    def sign_in(self):
        self.driver.get(self.base)
        token = self.find("#token")
        token.clear()
        token.send_keys(TOKEN)
        self.find("#signin-button").click()
        self.find("#signout")

    def identify(self, dataset):
        """Runs Hensen's settings (examples/two_tank_hensen.yaml), three passes,
        from the Identify page on `dataset`; returns the job's id once it succeeded."""
        self.go(f"identify?dataset={dataset}&model=two_tank")
        self.find("#theta0-A1")
        self.shot("identify")
        fields = {"passes": 3, "theta0-A1": 20, "theta0-A2": 20, "theta0-k1": 1, "theta0-k2": 1,
                  "p0-h1": 0, "p0-h2": 0, "p0-A1": 10, "p0-A2": 10, "p0-k1": 10, "p0-k2": 10,
                  "r-h1": 1e-3, "r-h2": 1e-3, "substeps": 10}
        for field, value in fields.items():
            element = self.driver.find_element(By.ID, field)
            element.clear()
            element.send_keys(str(value))
        self.find("#identify-submit").click()
        return self.wait_job()

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
        # This upload's row: a name another test uploaded too is another row.
        rows = self.wait(lambda d: [r for r in d.find_elements(By.CSS_SELECTOR, "#datasets tbody tr")
                                    if r.find_element(By.CSS_SELECTOR, "td.name").text == name
                                    and r.get_attribute("data-id") not in before])
        return rows[0].get_attribute("data-id")

    # -- the tests, in the order a user goes ---------------------------------
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
        self.assertEqual([a.text for a in self.driver.find_elements(By.CSS_SELECTOR, "#nav a")],
                         ["Datasets", "Identify", "Validate", "Sessions", "Models", "Jobs"])

    def test_2_upload_and_plot(self):
        self.sign_in()
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

    def upload_two_tank(self, name):
        csv = os.path.join(ARGS.source_dir, "tests/data/two_tank.csv")
        # With the parameters it was simulated with (tests/data/two_tank.json).
        return self.upload(csv, name, truth="A1:10, A2:5, k1:0.0791, k2:0.1342")

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
        job = self.identify(self.upload_two_tank("identify.csv"))
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
        # Hensen's estimates near the truth (two_tank.json: 10, 5, 0.0791, 0.1342).
        self.assertAlmostEqual(result["thetaMean"][0], 10, delta=1)
        self.find("#correlation")
        self.assert_plots_drawn("#traces", 4)
        self.assert_plots_drawn("#overlay", 2)
        self.shot("identify-result")

    def test_5_validate(self):
        self.sign_in()
        identified = self.identify(self.upload_two_tank("validate.csv"))
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

    def test_6_jobs_and_models(self):
        self.sign_in()
        job = self.identify(self.upload_two_tank("jobs.csv"))
        self.go("jobs")
        rows = self.wait(lambda d: (lambda r: r if job in [e.get_attribute("data-id") for e in r] else False)(
            d.find_elements(By.CSS_SELECTOR, "#jobs tbody tr")))
        self.assertIn(job, [r.get_attribute("data-id") for r in rows])
        self.shot("jobs")
        self.go("models")
        self.find('#model-list section[data-model="two_tank"]')
        # Units as the plugin declares them.
        unit = self.find('section[data-model="two_tank"] tr[data-param="k1"] td.unit')
        self.assertEqual(unit.text, "m^2.5/s")

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

    def stream_rows(self, rows, *args):
        """`riccati stream` as a rig: the first `rows` rows of the two-tank
        record (the rows after the session's t, when resuming one), at 50 Hz."""
        part = os.path.join(self.dir, f"two_tank_{rows}.csv")
        with open(os.path.join(ARGS.source_dir, "tests/data/two_tank.csv")) as f, open(part, "w") as out:
            out.writelines(line for i, line in zip(range(rows + 1), f))
        process = subprocess.Popen(
            [ARGS.riccati, "--server", f"127.0.0.1:{self.grpc_port}", "--token-file", self.token_file,
             "stream", "--data", part, "--rate", "50", "--keep", "--live", "never", *args],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        Workbench.stream = process  # stopped with the daemon, should the test end first
        return process

    def finished(self, process):
        _, err = process.communicate(timeout=WAIT)
        self.assertEqual(process.returncode, 0, err)
        return err

    def measurements_shown(self):
        summary = self.driver.find_element(By.ID, "session-summary").text
        return int(summary.split(" · ")[1].split()[0]) if " measurements" in summary else -1

    def test_7_session_live(self):
        # The rig streams in parts the test waits on, never against the
        # clock: a slow host takes longer, it does not time out. Its first
        # 100 rows make the session (kept open between parts).
        self.sign_in()
        err = self.finished(self.stream_rows(100, "--config", os.path.join(ARGS.source_dir, "examples/two_tank_hensen.yaml")))
        session = [w for line in err.splitlines() if line.startswith("session ") for w in line.split()[1:2]][0]
        self.go("sessions")
        link = self.wait(lambda d: [a for a in d.find_elements(By.CSS_SELECTOR, "#sessions tbody tr td a")
                                    if a.text == session])[0]
        self.shot("sessions")
        link.click()
        self.find("#session-summary")
        self.wait(lambda d: self.measurements_shown() == 100)
        # Estimates update as they come: the count shown follows each part
        # streamed while the page is open.
        for rows in (300, 500):
            streaming = self.stream_rows(rows, "--session", session)
            self.wait(lambda d: self.measurements_shown() == rows)
            self.finished(streaming)
        self.assert_plots_drawn("#session-plots", 6)

        # Retune on-line: R 1000 times larger. The filter leans on the model
        # now, so the uncertainty of h1 (its ±2σ) grows.
        def two_sigma(name):  # read at once: the table is redrawn at every estimate
            return self.driver.execute_script("""
                for (const tr of document.querySelectorAll('#session-values tbody tr')) {
                  if (tr.querySelector('th').textContent === arguments[0]) return Number(tr.querySelectorAll('td')[1].textContent);
                }
                return null;""", name)
        before = two_sigma("h1")
        self.assertIsNotNone(before)
        for output in ("h1", "h2"):
            self.find(f"#retune-r-{output}").send_keys("1")
        self.find("#retune-apply").click()
        self.wait(lambda d: d.find_element(By.ID, "retune-status").text != "")
        self.assertIn("Retuned", self.driver.find_element(By.ID, "retune-status").text)
        self.find("#retunings table tbody tr")
        info = self.api("/sessions/" + session)
        self.assertEqual(len(info["retunings"]), 1)
        self.assertEqual(info["retunings"][0]["r"]["diagonal"]["values"], [1, 1])
        # The filter retuned, the rig goes on: 500 rows more.
        streaming = self.stream_rows(1000, "--session", session)
        seen = []
        try:
            self.wait(lambda d: seen.append(two_sigma("h1")) or (seen[-1] or 0) > 1.5 * before)
        except TimeoutException:
            self.fail(f"the ±2σ of h1 did not grow after R was raised: {before} before, then {seen[-20:]}")
        self.wait(lambda d: self.measurements_shown() == 1000)
        self.finished(streaming)
        self.shot("session")


def main():
    global ARGS
    parser = argparse.ArgumentParser()
    parser.add_argument("--riccatid", required=True)
    parser.add_argument("--riccati", required=True)
    parser.add_argument("--models-dir", required=True)
    parser.add_argument("--source-dir", required=True)
    parser.add_argument("--screenshots", default="")
    ARGS, rest = parser.parse_known_args()
    unittest.main(argv=[sys.argv[0]] + rest, verbosity=2)


if __name__ == "__main__":
    main()
