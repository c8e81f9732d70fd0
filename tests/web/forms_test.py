#!/usr/bin/python3
"""The workbench's Identify form, made from riccatid's schema, against the CLI:
headless Chromium driven by Selenium and the `riccati` binary on one real riccatid.

  forms_test.py --riccatid build/bin/riccatid --riccati build/bin/riccati \
      --models-dir build/lib/riccati/models --source-dir . [--screenshots docs/figures]

For every method (filter, oe, ml) it submits from the form every setting
the CLI's tests use for it (tests/e2e/cli_e2e_test.cpp, the README), and the
same flags through the CLI on the same dataset: the two jobs' requests are
the same and their results equal to the bit. A field of another method is
hidden and not sent; a setting given where its method does not take it gets
riccatid's message, the same from the CLI and the JSON API; a dataset whose
columns are not the model's is refused before anything is sent; every flag
of `riccati identify --help` is a field of the form, or made on the page by
hand (model, dataset, experiments, masks), or given at upload.
"""
import json
import os
import re
import subprocess
import sys
import time
import unittest
import urllib.error

from selenium.webdriver.common.by import By
from selenium.webdriver.support.select import Select

sys.dont_write_bytecode = True  # no __pycache__ of workbench_test in the source tree
import workbench_test as wb  # noqa: E402 (after the line above)

# The flags of the CLI's tests, per method. Values as the CLI takes them;
# None: a switch, or a names flag given alone.
FILTER = [("--method", "filter"), ("--filter", "ekf"), ("--passes", "3"), ("--x0", "first"),
          ("--theta0", "20,20,1,1"), ("--p0", "0,0,10,10,10,10"), ("--q", "0"), ("--r", "1e-3"), ("--hold", "zoh"),
          ("--integrator", "rk4"), ("--substeps", "10"), ("--bound", "A1=1:100"), ("--end-sample", "1500")]
UKF = [("--filter", "ukf"), ("--x0", "first"), ("--weights", "scaled"), ("--alpha", "1"), ("--beta", "2"),
       ("--kappa", "0"), ("--passes", "2"), ("--theta0", "20,20,1,1"), ("--p0", "0,0,10,10,10,10"), ("--r", "1e-3"),
       ("--end-sample", "500")]
# README's output error, with log scales and bounds, two experiments, excluded samples and an output limit.
OE = [("--method", "oe"), ("--x0", "first"), ("--theta0", "20,20,1,1"), ("--output-sigma", "0.005,0.005"),
      ("--estimate-x0", None), ("--log-scale", "k1"), ("--log-scale", "k2"), ("--bound", "k1=0.001:1"),
      ("--bound", "k2=0.001:1"), ("--max-iterations", "50"), ("--integrator", "rk4"), ("--substeps", "10"),
      ("--exclude", "1@0:10"), ("--exclude", "2@100:200"), ("--output-limit", "h1=:10")]
# CTSM-R's method as the CLI's test runs it: R estimated, the first 500 samples.
ML = [("--method", "ml"), ("--x0", "first"), ("--theta0", "12,6,0.09,0.15"), ("--r", "1e-4"), ("--estimate-r", None),
      ("--p0", "2.5e-5,2.5e-5,0,0,0,0"), ("--end-sample", "500"), ("--max-iterations", "30"),
      ("--function-tolerance", "1e-10"), ("--fix", "A2")]


def given(value):
    """What a request in JSON (as riccatid prints it, defaults too) gives: its values other than the
    defaults (0, false, "", *_UNSPECIFIED) and empty objects and lists, which are what absent reads as."""
    if isinstance(value, dict):
        out = {k: given(v) for k, v in value.items()}
        return {k: v for k, v in out.items() if v is not None}
    if isinstance(value, list):
        return [given(v) if isinstance(v, dict) else v for v in value] or None
    if value in (0, "0", False, "") or (isinstance(value, str) and value.endswith("_UNSPECIFIED")):
        return None
    return value


class Forms(wb.WorkbenchCase):
    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.noisy = cls.cli_upload("two_tank_noisy.csv")
        cls.clean = cls.cli_upload("two_tank.csv")

    @classmethod
    def cli(cls, *args, check=True):
        run = subprocess.run([wb.ARGS.riccati, "--server", f"127.0.0.1:{cls.grpc_port}", "--token-file",
                              cls.token_file, *args], capture_output=True, text=True, timeout=wb.WAIT)
        if check and run.returncode != 0:
            raise AssertionError(f"riccati {' '.join(args)}: exit {run.returncode}: {run.stderr}")
        return run

    @classmethod
    def cli_upload(cls, name, outputs="h1,h2"):
        out = cls.cli("data", "upload", os.path.join(wb.ARGS.source_dir, "tests/data", name), "--inputs", "F1,F2",
                      "--outputs", outputs).stdout
        return out.split("\n")[0].strip()

    def wait_api_job(self, job):
        for _ in range(wb.WAIT * 10):
            state = self.api("/jobs/" + job)["state"]
            if state in ("JOB_STATE_SUCCEEDED", "JOB_STATE_FAILED", "JOB_STATE_CANCELLED"):
                self.assertEqual(state, "JOB_STATE_SUCCEEDED", self.api("/jobs/" + job).get("error"))
                return
            time.sleep(0.1)
        self.fail(f"job {job} did not end")

    def cli_job(self, dataset, settings):
        args = ["identify", "--model", "two_tank", "--data", dataset, "--no-wait"]
        for flag, value in settings:
            args += [flag] if value is None else [flag, value]
        job = self.cli(*args).stdout.split("\n")[0].strip()
        self.assertTrue(job.startswith("job-"), job)
        self.wait_api_job(job)
        return job

    def form_job(self, dataset, settings, screenshot=""):
        self.go(f"identify?model=two_tank&dataset={dataset}")
        self.find('[data-flag="--method"]')
        self.fill_settings(settings)
        if screenshot:
            self.shot(screenshot)
        self.find("#identify-submit").click()
        return self.wait_job()

    def assert_same_job(self, settings, dataset, screenshot=""):
        """The form and the CLI given the same settings: the same request, the same result to the bit."""
        cli = self.cli_job(dataset, settings)
        form = self.form_job(dataset, settings, screenshot)
        specs = [self.api("/jobs/" + j)["identification"] for j in (cli, form)]
        for spec in specs:
            spec.pop("requestId", None)
        self.assertEqual(specs[0], specs[1])
        results = [self.api(f"/jobs/{j}/result") for j in (cli, form)]
        for r in results:
            self.assertIn(r.pop("jobId"), (cli, form))
        # JSON's numbers are the doubles' shortest exact text: equal text, equal bits.
        self.assertEqual(json.dumps(results[0], sort_keys=True), json.dumps(results[1], sort_keys=True))
        return specs[1], results[1]

    # -- the tests -------------------------------------------------------------
    def test_0_sign_in(self):
        self.sign_in()

    def test_1_filter_as_the_cli(self):
        spec, result = self.assert_same_job(FILTER, self.clean)
        self.assertEqual(spec["passes"], 3)
        self.assertEqual(len(result["identification"]["passes"]), 3)

    def test_2_ukf_as_the_cli(self):
        spec, _ = self.assert_same_job(UKF, self.clean)
        self.assertEqual(spec["filter"]["ukf"], {"weights": "SIGMA_WEIGHTS_SCALED", "alpha": 1, "beta": 2, "kappa": 0})

    def test_3_output_error_as_the_cli(self):
        spec, result = self.assert_same_job(OE + [("--experiment", self.clean)], self.noisy, screenshot="identify-oe")
        self.assertEqual(spec["method"], "IDENTIFICATION_METHOD_OE")
        self.assertEqual(spec["initialState"]["estimate"], ["all"])
        self.assertEqual(spec["mask"]["excluded"], [{"first": "0", "end": "10"}])
        self.assertEqual(spec["experiments"][0]["mask"]["excluded"], [{"first": "100", "end": "200"}])
        self.assertEqual(spec["experiments"][0]["mask"]["limits"], [{"output": "h1", "upper": 10}])
        self.assertEqual(spec["estimation"]["outputSigma"], [0.005, 0.005])
        self.assertEqual(len(result["estimation"]["experiments"]), 2)

    def test_4_likelihood_as_the_cli(self):
        spec, result = self.assert_same_job(ML, self.noisy)
        self.assertTrue(spec["estimation"]["estimateMeasurementNoise"])
        self.assertEqual(spec["fixed"], [{"name": "A2"}])
        self.assertEqual(result["estimation"]["method"], "IDENTIFICATION_METHOD_ML")

    def test_5_fields_of_another_method_are_hidden_and_not_sent(self):
        self.go(f"identify?model=two_tank&dataset={self.clean}")
        passes = self.find('.settings-form [data-flag="--passes"]:not(.setting)')
        sigma = self.driver.find_element(By.CSS_SELECTOR, '.setting[data-flag="--output-sigma"]')
        self.assertTrue(passes.is_displayed())
        self.assertFalse(sigma.is_displayed())  # oe's, and the method is riccatid's default, filter
        # R in full (rows separated by ';'), and a bound at infinity (JSON's "Infinity").
        self.fill_settings([("--passes", "7"), ("--r", "1e-3, 0; 0, 1e-3"), ("--method", "oe"),
                            ("--theta0", "20,20,1,1"), ("--bound", "A1=1:inf")])
        self.assertFalse(passes.is_displayed())
        self.assertTrue(sigma.is_displayed())
        # The filter kind's settings follow the kind: the UKF's appear for it only.
        alpha = self.driver.find_element(By.CSS_SELECTOR, '.setting[data-flag="--alpha"]')
        self.assertFalse(alpha.is_displayed())
        Select(self.find('[data-flag="--filter"]:not(.setting)')).select_by_value("ukf")
        self.assertTrue(alpha.is_displayed())
        Select(self.find('[data-flag="--filter"]:not(.setting)')).select_by_value("ekf")
        self.find("#identify-submit").click()
        job = self.wait_job()
        spec = given(self.api("/jobs/" + job)["identification"])
        self.assertNotIn("passes", spec)  # typed, then hidden: not sent
        self.assertEqual(spec["method"], "IDENTIFICATION_METHOD_OE")
        self.assertEqual(spec["filter"], {"kind": "FILTER_KIND_EKF",
                                          "r": {"full": {"rows": 2, "cols": 2, "values": [1e-3, 0, 0, 1e-3]}}})
        self.assertEqual(spec["bounds"], [{"name": "A1", "lower": 1, "upper": "Infinity"}])
        # Nothing left empty was sent: no client-side defaults (P0, x0, substeps are riccatid's).
        self.assertEqual(sorted(spec), ["bounds", "datasetId", "filter", "method", "model", "theta0"])

    def test_6_a_misplaced_setting_gets_riccatids_message_everywhere(self):
        message = "passes applies to method filter only, not to oe"
        run = self.cli("identify", "--model", "two_tank", "--data", self.clean, "--method", "oe", "--passes", "3",
                       "--no-wait", check=False)
        self.assertNotEqual(run.returncode, 0)
        self.assertIn(message, run.stderr)
        # The JSON the workbench sends, with the field its form hides for oe.
        with self.assertRaises(urllib.error.HTTPError) as e:
            self.api("/jobs/identification", {"model": "two_tank", "datasetId": self.clean,
                                              "method": "IDENTIFICATION_METHOD_OE", "passes": 3})
        self.assertEqual(e.exception.code, 400)
        self.assertIn(message, json.loads(e.exception.read())["message"])
        # What riccatid refuses at submit is shown on the form, its message as riccatid wrote it.
        self.go(f"identify?model=two_tank&dataset={self.clean}")
        self.fill_settings([("--method", "oe"), ("--bound", "A3=0:1")])
        self.find("#identify-submit").click()
        error = self.wait(lambda d: d.find_element(By.CSS_SELECTOR, "#identify-status .error"))
        self.assertIn('bounds: model two_tank has no parameter "A3" (its parameters: A1, A2, k1, k2)', error.text)
        # Text a field cannot take is refused before anything is sent, naming the flag.
        self.fill_settings([("--theta0", "20,x,1,1")])
        self.find("#identify-submit").click()
        self.wait(lambda d: '--theta0: "x" is not a number' in d.find_element(By.ID, "identify-status").text)

    def test_7_columns_that_do_not_match_are_refused_before_submit(self):
        one_output = self.cli_upload("two_tank.csv", outputs="h1")
        jobs = len(self.api("/jobs").get("jobs", []))
        self.go(f"identify?model=two_tank&dataset={one_output}")
        note = self.wait(lambda d: d.find_element(By.CSS_SELECTOR, "#identify-columns .error"))
        self.assertIn("model two_tank has 2 outputs (h1, h2), dataset two_tank.csv has 1 (h1)", note.text)
        self.assertFalse(self.find("#identify-submit").is_enabled())
        self.assertEqual(len(self.api("/jobs").get("jobs", [])), jobs)
        Select(self.find("#dataset")).select_by_value(self.clean)
        self.wait(lambda d: d.find_element(By.ID, "identify-columns").text == "")
        self.assertTrue(self.find("#identify-submit").is_enabled())
        # An experiment's dataset is checked as well.
        self.fill_settings([("--method", "oe"), ("--experiment", one_output)])
        note = self.wait(lambda d: d.find_element(By.CSS_SELECTOR, "#identify-columns .error"))
        self.assertIn("dataset two_tank.csv has 1 (h1)", note.text)
        self.assertFalse(self.find("#identify-submit").is_enabled())
        self.assertEqual(len(self.api("/jobs").get("jobs", [])), jobs)

    def test_8_every_flag_of_the_cli_is_in_the_form(self):
        flags = set(re.findall(r"^\s+(?:-\w,)?(--[a-z0-9-]+)", self.cli("identify", "--help").stdout, re.M))
        self.go(f"identify?model=two_tank&dataset={self.clean}")
        self.find('[data-flag="--method"]')
        in_form = {e.get_attribute("data-flag")
                   for e in self.driver.find_elements(By.CSS_SELECTOR, ".setting[data-flag]")}
        # Made by hand on the page (the model and dataset chosen, experiments, masks); given at upload on the
        # Datasets page (columns, truth); the CLI's own (a job file, not waiting).
        elsewhere = {"--model", "--data", "--experiment", "--exclude", "--output-limit", "--inputs", "--outputs",
                     "--truth", "--config", "--no-wait", "--help"}
        self.assertGreater(len(flags), 40)
        self.assertEqual(flags - elsewhere - in_form, set())
        self.assertEqual(in_form - flags, set())  # and nothing the CLI does not take


def main():
    wb.main_args()
    unittest.main(argv=[sys.argv[0]] + wb.REST, verbosity=2)


if __name__ == "__main__":
    main()
