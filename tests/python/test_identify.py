"""Identification, validation and jobs through a real riccatid."""
import dataclasses
import io
import json
import os
import subprocess

import numpy as np
import pandas as pd
import pytest

import riccati
from conftest import CLI, DATA
from riccati.v1 import jobs_pb2

# Hensen's settings (examples/two_tank_hensen.yaml), keyword for flag.
HENSEN = dict(filter="ekf", passes=10, x0="first", theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10], q=0,
              r=[1e-3, 1e-3], hold="zoh", integrator="rk4", substeps=10)
IO = dict(inputs=["F1", "F2"], outputs=["h1", "h2"])


@pytest.fixture(scope="module")
def truth():
    with open(os.path.join(DATA, "two_tank.json")) as f:
        reference = json.load(f)
    return pd.Series(reference["parameters"])[reference["parameter_order"]]


@pytest.fixture(scope="module")
def hensen(daemon, two_tank_csv):
    """Hensen's identification, once for the module: (client, dataset, job, result, progress seen)."""
    c = riccati.Client(daemon.address)
    ds = c.upload(two_tank_csv, **IO)
    seen = []
    job = c.submit_identification("two_tank", ds, **HENSEN)
    result = job.result(progress=seen.append)
    yield c, ds, job, result, [(j.state, j.progress) for j in seen]
    c.close()


def test_identify_finds_the_true_parameters(hensen, truth):
    _, _, job, res, _ = hensen
    assert isinstance(res, riccati.IdentificationResult)
    assert list(res.theta.index) == ["A1", "A2", "k1", "k2"]
    # Hensen's noiseless record: every parameter within 2 % of the truth it was simulated with.
    error = (res.theta - truth) / truth
    assert (error.abs() < 0.02).all(), error
    assert (res.std > 0).all() and (res.std < 0.01 * res.theta).all()
    assert job.state == "succeeded"


def test_result_is_what_riccatid_sent(hensen):
    _, _, _, res, _ = hensen
    r = res.proto
    np.testing.assert_array_equal(res.theta.to_numpy(), list(r.theta_mean))
    np.testing.assert_array_equal(res.theta_final.to_numpy(), list(r.theta))
    np.testing.assert_array_equal(res.std.to_numpy(), list(r.theta_std))
    np.testing.assert_array_equal(res.filter_std.to_numpy(), list(r.filter_theta_std))
    assert res.covariance_method.startswith("output error at the estimate: ")
    # The std errors' covariance (ntheta x ntheta, column-major), by index; the
    # filter's P's parameter block beside it (nz x nz).
    assert r.theta_covariance.rows == 4
    for i in range(4):
        for j in range(4):
            assert res.covariance.iloc[i, j] == r.theta_covariance.values[i + j * 4]
            assert res.filter_covariance.iloc[i, j] == r.covariance.values[(2 + i) + (2 + j) * r.covariance.rows]
    np.testing.assert_allclose(np.sqrt(np.diag(res.covariance)), res.std, rtol=1e-12)
    np.testing.assert_allclose(np.diag(res.correlation), 1.0, rtol=1e-12)
    c01 = res.covariance.iloc[0, 1] / np.sqrt(res.covariance.iloc[0, 0] * res.covariance.iloc[1, 1])
    assert res.correlation.loc["A1", "A2"] == pytest.approx(c01, rel=1e-12)
    # The 95 % interval holds the reported estimate and the optimum's interval,
    # one Gauss-Newton step (theta_step) away.
    np.testing.assert_array_equal(res.ci["lower"].to_numpy(), list(r.ci_lower))
    np.testing.assert_array_equal(res.ci["upper"].to_numpy(), list(r.ci_upper))
    assert (res.ci["lower"] <= res.theta).all() and (res.theta <= res.ci["upper"]).all()
    optimum = res.theta + res.theta_step
    assert (res.ci["lower"] <= optimum - 1.959963984540054 * res.std * (1 - 1e-12)).all()
    assert (optimum + 1.959963984540054 * res.std * (1 - 1e-12) <= res.ci["upper"]).all()
    summary = res.summary()
    assert list(summary.columns) == ["estimate", "std", "lower", "upper", "rel_std_percent", "filter_std", "final"]
    np.testing.assert_array_equal(summary["estimate"].to_numpy(), list(r.theta_mean))
    np.testing.assert_array_equal(summary["final"].to_numpy(), list(r.theta))
    assert repr(res).startswith(f"<IdentificationResult of job {res.job_id}, model two_tank: iterated filter, 10 passes")


def test_traces_are_every_pass_sample_by_sample(hensen):
    _, _, _, res, _ = hensen
    samples = len(res.proto.t)
    assert samples == 2000
    assert res.traces.shape == (10 * samples, 4)
    for k in range(1, 11):
        last = res.traces.loc[k].iloc[-1]
        np.testing.assert_array_equal(last.to_numpy(), list(res.proto.passes[k - 1].theta_final))
    # The toolbox's estimate is the last pass's mean, which the trace gives independently.
    np.testing.assert_allclose(res.traces.loc[10].mean().to_numpy(), res.theta.to_numpy(), rtol=1e-9)
    frame = res.to_frame()
    assert list(frame.columns) == ["h1", "h2", "y_model.h1", "y_model.h2", "innovation.h1", "innovation.h2"]
    assert len(frame) == samples and frame.index[0] == 0.0


def test_progress_callback_sees_the_job_run_to_its_end(hensen):
    _, _, _, _, seen = hensen
    assert seen[-1][0] == "succeeded"
    assert seen[-1][1].pass_number == 10 and seen[-1][1].passes == 10
    fractions = [p.fraction for state, p in seen if state == "running"]
    assert fractions == sorted(fractions)


def test_the_cli_reads_the_same_result(hensen, daemon):
    _, _, job, res, _ = hensen
    out = subprocess.run([CLI, "--server", daemon.address, "result", job.id, "--format", "json"], check=True,
                         capture_output=True, text=True).stdout
    cli = json.loads(out)["identification"]
    assert cli["param_names"] == list(res.theta.index)
    assert cli["theta_mean"] == res.theta.tolist()
    assert cli["theta_std"] == res.std.tolist()


def test_validate_predicts_k_steps_ahead_with_the_jobs_filter(hensen):
    c, ds, job, _, _ = hensen
    simulated = c.validate("two_tank", ds, job)
    ahead = c.validate("two_tank", ds, job, horizon=5)
    assert simulated.horizon == 0 and ahead.horizon == 5
    assert ahead.predictor == (f"ekf of job {job.id} (Q as the job ran, R as the job ran, the states' P0), "
                               "5 samples ahead")
    # Hensen's filter has Q = 0 and the states' P0 = 0: it never corrects them, so
    # its predictions are the simulation's own (to rounding: each restarts from the
    # filter's state, which it integrated with its covariance).
    np.testing.assert_allclose(ahead.to_frame().to_numpy(), simulated.to_frame().to_numpy(), rtol=1e-12, atol=1e-15)
    with pytest.raises(riccati.InvalidArgument, match="horizon 2 needs an identification job's estimate"):
        c.validate("two_tank", ds, [10, 5, 0.0791, 0.1342], horizon=2)
    # Below the schema's minimum: refused before anything is sent, as the CLI refuses --horizon 0.
    with pytest.raises(ValueError, match="horizon: 0 is below the least value, 1"):
        c.validate("two_tank", ds, job, horizon=0)


def test_validate_fits_agree_with_the_simulated_outputs(hensen):
    c, ds, job, res, _ = hensen
    fit = c.validate("two_tank", ds, job)
    assert isinstance(fit, riccati.ValidationResult)
    np.testing.assert_array_equal(fit.theta.to_numpy(), res.theta.to_numpy())  # the job's reported estimate
    frame = fit.to_frame()
    # MATLAB's compare: 100 (1 - |y - yhat| / |y - mean(y)|), recomputed from the samples.
    for o in ("h1", "h2"):
        y, yhat = frame[f"y.{o}"].to_numpy(), frame[f"y_model.{o}"].to_numpy()
        expected = 100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean()))
        assert fit.fits.loc[o, "fit_percent"] == pytest.approx(expected, rel=1e-9)
        assert fit.fits.loc[o, "rmse"] == pytest.approx(np.sqrt(np.mean((y - yhat) ** 2)), rel=1e-9)
        assert fit.fits.loc[o, "fit_percent"] > 99
    # The measured outputs are the uploaded ones.
    data = pd.read_csv(os.path.join(DATA, "two_tank.csv"), float_precision="round_trip")
    np.testing.assert_array_equal(frame["y.h1"].to_numpy(), data["h1"].to_numpy())
    np.testing.assert_array_equal(frame["residual.h2"].to_numpy(), (frame["y.h2"] - frame["y_model.h2"]).to_numpy())
    # Given values: the same simulation.
    again = c.validate("two_tank", ds, res.theta)
    np.testing.assert_array_equal(again.to_frame().to_numpy(), frame.to_numpy())


def test_compare_ranks_fits_and_tests_a_nested_pair_as_the_cli_does(client, daemon):
    ds = client.upload(os.path.join(DATA, "two_tank_noisy.csv"), **IO)
    free = client.submit_identification("two_tank", ds, method="oe", theta0=[11, 6, 0.09, 0.15])
    held = client.submit_identification("two_tank", ds, method="oe", theta0=[11, 6, 0.09, 0.15], fix=["k2=0.12"])
    free.result(), held.result()
    c = client.compare(free, held.id)
    assert isinstance(c, riccati.Comparison)
    assert list(c.table.index) == [free.id, held.id]
    assert list(c.table["k"]) == [5, 4]
    ll, k, n = c.table["log_likelihood"], c.table["k"], c.table["n"]
    np.testing.assert_allclose(c.table["aic"], 2 * k - 2 * ll, rtol=1e-12)
    assert c.table.loc[free.id, "lowest_aic"] and not c.table.loc[held.id, "lowest_aic"]
    assert c.table.loc[free.id, "fit_percent.h1"] > 90
    assert len(c.tests) == 1
    test = c.tests.iloc[0]
    assert (test["smaller"], test["larger"], test["dof"]) == (held.id, free.id, 1)
    assert test["statistic"] == pytest.approx(2 * (ll[free.id] - ll[held.id]), rel=1e-12)
    assert test["p"] < 1e-6 and test["significant"]
    # The CLI prints the same answer: riccatid's.
    out = subprocess.run([CLI, "--server", daemon.address, "--json", "compare", free.id, held.id], check=True,
                         capture_output=True, text=True).stdout
    cli = json.loads(out)
    assert [j["aic"] for j in cli["jobs"]] == list(c.table["aic"])
    assert cli["likelihood_ratio_tests"][0]["p"] == test["p"]
    with pytest.raises(riccati.InvalidArgument, match="compare takes at most 20 jobs"):
        client.compare(*([free.id] * 21))


def test_compare_on_a_common_validation_record(client):
    """Each fit validated on the noise-free record: the fits riccatid sets side by
    side are those of each job's own validation, and the true model (all four
    free) fits it better than the one with k2 held wrong; the record is common to
    all, and validations that are not are refused, naming them."""
    noisy = client.upload(os.path.join(DATA, "two_tank_noisy.csv"), **IO)
    clean = client.upload(os.path.join(DATA, "two_tank.csv"), **IO)
    free = client.submit_identification("two_tank", noisy, method="oe", theta0=[11, 6, 0.09, 0.15])
    held = client.submit_identification("two_tank", noisy, method="oe", theta0=[11, 6, 0.09, 0.15], fix=["k2=0.12"])
    free.result(), held.result()
    c = client.compare(free, held, data=clean)
    assert c.validation_dataset == clean.id and c.validation_horizon == 0
    for job in (free, held):
        alone = client.validate("two_tank", clean, job)
        for output in ("h1", "h2"):
            assert c.table.loc[job.id, "validation_fit_percent." + output] == alone.fits.loc[output, "fit_percent"]
    assert c.table.loc[free.id, "validation_fit_percent.h2"] > c.table.loc[held.id, "validation_fit_percent.h2"]
    # K steps ahead: output error's noise model has no process noise (Q = 0, P0 = 0),
    # so its filter never corrects the states and its predictions are its simulation.
    k1 = client.compare(free, held, data=clean, horizon=1)
    assert k1.validation_horizon == 1
    np.testing.assert_allclose(k1.table["validation_fit_percent.h2"], c.table["validation_fit_percent.h2"], rtol=1e-9)
    assert set(k1.table["validation_job"]).isdisjoint(c.table["validation_job"])
    # Validations not on one record, or of a job not compared: refused.
    on_noisy = client.submit_validation("two_tank", noisy, held)
    on_noisy.result()
    request = jobs_pb2.CompareJobsRequest(
        job_ids=[free.id, held.id], validation_job_ids=[c.table.loc[free.id, "validation_job"], on_noisy.id])
    with pytest.raises(riccati.InvalidArgument, match="not on one common record"):
        client._call("comparing", client._jobs.CompareJobs, request)
    request = jobs_pb2.CompareJobsRequest(job_ids=[free.id], validation_job_ids=[on_noisy.id])
    with pytest.raises(riccati.InvalidArgument, match=f"is of job {held.id}, which is not among the jobs compared"):
        client._call("comparing", client._jobs.CompareJobs, request)
    with pytest.raises(TypeError, match="horizon needs data"):
        client.compare(free, held, horizon=3)


def test_output_error_with_intervals(client, truth):
    noisy = os.path.join(DATA, "two_tank_noisy.csv")
    res = client.identify("two_tank", noisy, method="oe", theta0=[20, 20, 1, 1], output_sigma=[0.005, 0.005],
                          estimate_x0=True, **IO)
    assert isinstance(res, riccati.EstimationResult)
    assert res.method == "oe" and res.converged
    # The truth lies within a few standard errors (the noise is that of the record).
    assert (((res.theta - truth) / res.std).abs() < 4).all()
    assert (res.ci["lower"] < res.theta).all() and (res.theta < res.ci["upper"]).all()
    assert res.covariance_method  # white, or robust where the residuals are not
    assert res.correlation.loc["A1", "A1"] == pytest.approx(1.0)
    assert res.correlation.shape == (4, 4)
    assert len(res.traces) == res.iterations or len(res.traces) == res.iterations + 1
    assert res.traces["cost"].iloc[-1] == pytest.approx(res.cost)
    frame = res.to_frame()
    outputs = ["h1", "h2"]
    assert list(frame.columns) == [f"{q}.{o}" for q in ("y", "y_model", "residual", "residual_normalised", "used")
                                   for o in outputs]
    # The raw residual in the output's unit; the normalised one is it over the sigma given (OE).
    np.testing.assert_array_equal(frame["residual.h1"].to_numpy(), (frame["y.h1"] - frame["y_model.h1"]).to_numpy())
    np.testing.assert_allclose(frame["residual_normalised.h1"].to_numpy(), frame["residual.h1"].to_numpy() / 0.005,
                               rtol=1e-9, atol=1e-12)
    assert res.experiments[0].x0.index.tolist() == ["h1", "h2"]
    assert set(res.fits.index) == {"h1", "h2"}
    # The residual tests named by the model's outputs and inputs, with riccatid's p-values and dof.
    diag = res.experiments[0].diagnostics
    assert diag.whiteness.index.tolist() == ["h1", "h2"]
    assert diag.independence.index.tolist() == [("h1", "F1"), ("h1", "F2"), ("h2", "F1"), ("h2", "F2")]
    assert (diag.whiteness["dof"] == diag.lags).all()
    for table in (diag.whiteness, diag.independence):
        assert table["p_value"].dropna().between(0, 1).all()
        assert ((table["p_value"] < 0.05) == (table["verdict"] == "fail")).all()
    assert diag.whiteness["p_value"].notna().all()


def test_refusals_carry_the_code_and_message(client, two_tank_csv):
    with pytest.raises(riccati.NotFound) as e:
        client.identify("no_such_model", two_tank_csv, **IO)
    assert e.value.code.name == "NOT_FOUND" and "no_such_model" in e.value.message
    with pytest.raises(riccati.InvalidArgument) as e:
        client.identify("two_tank", two_tank_csv, r=[1e-3, 1e-3, 1e-3], **IO)
    assert e.value.code.name == "INVALID_ARGUMENT"
    # R given three values for the two outputs: the field and the count.
    assert "filter.r.diagonal needs 2 values, got 3" in e.value.message, e.value.message
    with pytest.raises(ValueError, match="ekf"):
        client.submit_identification("two_tank", "some-id", filter="kalman")
    with pytest.raises(TypeError, match="passs"):
        client.submit_identification("two_tank", "some-id", passs=3)


def test_a_cancelled_job_raises_job_failed(client, two_tank_csv):
    job = client.submit_identification("two_tank", two_tank_csv, passes=4000, theta0=[20, 20, 1, 1],
                                       p0=[0, 0, 10, 10, 10, 10], r=1e-3, **IO)
    for seen in job.watch():
        if seen.state == "running":
            break
    job.cancel()
    with pytest.raises(riccati.JobFailed) as e:
        job.result()
    assert job.state == "cancelled"
    assert e.value.code.name == "CANCELLED"
    assert job.progress.pass_number < 4000


def test_columns_named_as_the_models_need_no_mapping(client, two_tank_csv):
    settings = dict(passes=2, theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10], r=1e-3)
    named = client.identify("two_tank", two_tank_csv, **settings)
    mapped = client.identify("two_tank", two_tank_csv, **settings, **IO)
    np.testing.assert_array_equal(named.theta.to_numpy(), mapped.theta.to_numpy())
    uploaded = client.job(named.job_id).proto.identification.dataset_id
    assert client.dataset(uploaded).input_names == ["F1", "F2"]


def test_plots_of_traces_and_of_a_validation_are_written(hensen, tmp_path):
    import xml.etree.ElementTree as ET
    c, ds, job, res, _ = hensen
    traces = tmp_path / "traces.png"
    fig = res.plot_traces(traces)
    assert len(fig.axes) == 4  # a subplot per parameter
    # The passes one after the other: 10 passes of 2000 samples on each subplot's line.
    passes = [line for line in fig.axes[0].lines if len(line.get_xdata()) > 2]  # not the marker lines
    assert [len(line.get_xdata()) for line in passes] == [2000] * 10
    np.testing.assert_array_equal(passes[-1].get_ydata(), res.traces.loc[10, "A1"].to_numpy())
    data = traces.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 20000
    fit = c.validate("two_tank", ds, job)
    overlay = tmp_path / "fit.svg"
    fig = fit.plot(overlay)
    assert [ax.get_ylabel() for ax in fig.axes] == ["h1", "h2"]
    np.testing.assert_array_equal(fig.axes[0].lines[1].get_ydata(), fit.to_frame()["y_model.h1"].to_numpy())
    root = ET.parse(overlay).getroot()  # parses as XML: an SVG document
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    assert len(root.findall(".//{http://www.w3.org/2000/svg}path")) > 10


def test_an_output_error_result_explains_itself_and_plots(client, daemon, tmp_path):
    seen = []
    job = client.submit_identification("two_tank", os.path.join(DATA, "two_tank.csv"), method="oe",
                                       theta0=[20, 20, 1, 1], **IO)
    res = job.result(progress=lambda j: seen.append((j.state, j.progress)))
    assert isinstance(res, riccati.EstimationResult)
    # Progress: the optimiser's iterations of max_iterations (200 by default), not stuck at 0.
    iterating = [(state, p) for state, p in seen if p.iteration > 0]
    assert iterating, seen
    assert all(p.method == "oe" and p.max_iterations == 200 for _, p in iterating)
    fractions = [p.fraction for state, p in iterating if state != "succeeded"]
    assert fractions == sorted(fractions)
    assert seen[-1][0] == "succeeded" and seen[-1][1].fraction == 1.0
    last = dataclasses.replace(seen[-1][1], succeeded=False)  # as it was before the end
    assert last.iteration == res.iterations
    assert last.fraction == pytest.approx(res.iterations / 200) and last.fraction > 0
    assert str(last) == f"iteration {res.iterations}/200, cost {last.cost:.4g}"

    # What it says of itself: the method, the job, the estimate.
    text = repr(res)
    assert text.startswith(f"<EstimationResult of job {job.id}, model two_tank: oe, converged after ")
    assert f"A1 = {res.theta['A1']:.6g}" in text
    assert res.gradient == res.proto.gradient and "forward sensitivities" in res.gradient
    assert f"gradient: {res.gradient}" in str(res)
    summary = res.summary()
    assert list(summary.columns) == ["estimate", "std", "lower", "upper", "rel_std_percent", "fixed"]
    assert list(summary.index) == ["A1", "A2", "k1", "k2"]
    np.testing.assert_array_equal(summary["estimate"].to_numpy(), list(res.proto.theta))
    np.testing.assert_array_equal(summary["upper"].to_numpy(), list(res.proto.ci_upper))
    np.testing.assert_allclose(summary["rel_std_percent"].to_numpy(),
                               100 * np.asarray(res.proto.theta_std) / np.abs(res.proto.theta), rtol=1e-12)
    # The likelihood and the criteria, as riccatid computed them: k the four
    # parameters and sigma^2 (not given), n both outputs' samples.
    c = res.criteria
    assert (c["k"], c["n"]) == (5, 2 * 2000) == (res.proto.estimated_quantities, res.proto.samples)
    assert c["log_likelihood"] == res.proto.log_likelihood
    assert c["aic"] == pytest.approx(2 * 5 - 2 * c["log_likelihood"], rel=1e-12)
    assert c["bic"] == pytest.approx(5 * np.log(4000) - 2 * c["log_likelihood"], rel=1e-12)
    printed = str(res)
    assert f"AIC {c['aic']:.10g}, AICc {c['aicc']:.10g}, BIC {c['bic']:.10g} (k = 5 estimated, n = 4000)" in printed
    assert printed.startswith(f"oe estimate of two_tank, job {job.id}: converged after {res.iterations} iterations")
    assert summary.to_string() in printed and "experiment 1 (ds-" in printed

    # The figure: per output the fit, then the residual.
    fig = res.plot(tmp_path / "oe.png")
    assert [ax.get_ylabel() for ax in fig.axes] == ["h1", "residual h1", "h2", "residual h2"]
    frame = res.to_frame()
    np.testing.assert_array_equal(fig.axes[1].lines[0].get_ydata(), frame["residual.h1"].to_numpy())
    assert (tmp_path / "oe.png").read_bytes().startswith(b"\x89PNG")

    # The CLI's CSV has the same columns as to_frame(), and the same values.
    out = subprocess.run([CLI, "--server", daemon.address, "result", job.id, "--format", "csv"], check=True,
                         capture_output=True, text=True).stdout
    csv = pd.read_csv(io.StringIO(out), float_precision="round_trip")
    assert list(csv.columns) == ["experiment", "t"] + list(frame.columns)
    np.testing.assert_array_equal(csv["residual.h2"].to_numpy(), frame["residual.h2"].to_numpy())
    np.testing.assert_array_equal(csv["used.h1"].to_numpy(), frame["used.h1"].astype(float).to_numpy())
