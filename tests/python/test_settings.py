"""Keywords made from the API's schema: the same settings as riccatid's, riccatid's refusals as it words them."""
import inspect
import json
import os
import re
import subprocess
import urllib.request

import numpy as np
import pytest

import riccati
from riccati import _settings
from riccati.v1 import jobs_pb2, models_pb2, sessions_pb2
from conftest import CLI, Daemon

IO = dict(inputs=["F1", "F2"], outputs=["h1", "h2"])
REQUESTS = {"IdentificationSpec": jobs_pb2.IdentificationSpec, "SmoothingSpec": jobs_pb2.SmoothingSpec,
            "ValidationSpec": jobs_pb2.ValidationSpec, "CreateSessionRequest": sessions_pb2.CreateSessionRequest,
            "SimulateRequest": models_pb2.SimulateRequest}


@pytest.fixture(scope="module")
def schema(tmp_path_factory):
    """riccatid's own walk of the same options: GET /api/v1/schema."""
    work = str(tmp_path_factory.mktemp("schema"))
    port_file = os.path.join(work, "http_port")
    d = Daemon(work, "--http-listen", "127.0.0.1:0", "--http-port-file", port_file)
    try:
        with open(port_file) as f:
            port = f.read().strip()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/schema", timeout=30) as response:
            yield json.loads(response.read())
    finally:
        assert d.stop() == 0


def test_the_keywords_are_riccatids_settings(schema):
    for name, message in REQUESTS.items():
        mine = [(s.path, s.keyword, s.kind) for s in _settings.settings_of(message).values()]
        theirs = [(s["path"], s["keyword"], s["kind"]) for s in schema["requests"][name]]
        assert mine == theirs, name
    # Beside what the CLI's tests use, settings only the schema lists reach Python: the integrator's step bound.
    assert _settings.settings_of(jobs_pb2.IdentificationSpec)["max_steps"].path == "filter.integrator.max_steps"


def test_every_flag_of_the_cli_is_a_keyword():
    help_text = subprocess.run([CLI, "identify", "--help"], capture_output=True, text=True, check=True).stdout
    flags = set(re.findall(r"^\s+(?:-\w,)?--([a-z0-9-]+)", help_text, re.M))
    assert len(flags) > 40
    keywords = {*_settings.settings_of(jobs_pb2.IdentificationSpec), *_settings.IDENTIFY_EXTRAS,
                *inspect.signature(riccati.Client.submit_identification).parameters}
    # model and data are identify()'s first arguments; a job file, not waiting and help are the CLI's own;
    # the truth is given at upload (true_parameters=).
    cli_only = {"model", "data", "config", "no_wait", "help", "truth"}
    assert {f.replace("-", "_") for f in flags} - keywords - cli_only == set()


def test_a_setting_of_another_method_gets_riccatids_message(client, two_tank_csv):
    ds = client.upload(two_tank_csv, **IO)
    with pytest.raises(riccati.InvalidArgument) as e:
        client.submit_identification("two_tank", ds, method="oe", passes=3, theta0=[20, 20, 1, 1])
    assert "passes applies to method filter only, not to oe" in e.value.message
    with pytest.raises(riccati.InvalidArgument) as e:
        client.submit_identification("two_tank", ds, filter="ekf", alpha=1.0, r=1e-3)
    assert "filter.ukf.alpha applies to the ukf filter only, not to the ekf filter" in e.value.message
    assert not [j for j in client.jobs() if j.proto.identification.dataset_id == ds.id]  # refused at submit


def test_an_unknown_keyword_names_the_close_ones(client):
    with pytest.raises(TypeError) as e:
        client.submit_identification("two_tank", "ds-none", passs=3)
    assert "unknown setting 'passs' (did you mean passes" in str(e.value)
    with pytest.raises(TypeError, match="'substep' \\(did you mean substeps"):
        client.submit_smoothing("two_tank", "ds-none", substep=5)
    # Smoothing runs a filter: the settings of output error and likelihood are not offered for it.
    with pytest.raises(TypeError, match="unknown setting 'estimate_x0'"):
        client.submit_smoothing("two_tank", "ds-none", estimate_x0=True)


def test_values_are_written_as_the_cli_writes_them():
    spec = jobs_pb2.IdentificationSpec()
    rest = _settings.fill(spec, dict(method="oe", x0="first", estimate_x0=True, log_scale="k1,k2",
                                     bound=["k1=0.001:1", "k2=:1"], fix="A2", r=1e-4, p0=[1, 2], q=[[1, 2], [2, 5]],
                                     max_iterations=30, estimate_r=False, exclude=[(0, 10)]))
    assert rest == {"exclude": [(0, 10)]}  # not a setting: the caller's
    assert spec.method == jobs_pb2.IDENTIFICATION_METHOD_OE
    assert spec.initial_state.first_measurement and list(spec.initial_state.estimate) == ["all"]
    assert list(spec.log_scale) == ["k1", "k2"]
    assert [(b.name, b.HasField("lower"), b.upper) for b in spec.bounds] == [("k1", True, 1.0), ("k2", False, 1.0)]
    assert [(f.name, f.HasField("value")) for f in spec.fixed] == [("A2", False)]
    assert spec.filter.r.scalar == 1e-4 and list(spec.p0.diagonal.values) == [1, 2]
    assert list(spec.filter.q.full.values) == [1, 2, 2, 5]
    assert spec.estimation.max_iterations == 30 and not spec.estimation.estimate_measurement_noise
    with pytest.raises(ValueError, match="ekff"):
        _settings.fill(jobs_pb2.IdentificationSpec(), dict(filter="ekff"))
    with pytest.raises(ValueError, match="passes: expected a whole number"):
        _settings.fill(jobs_pb2.IdentificationSpec(), dict(passes=2.5))


def test_smooth_takes_params_as_the_cli(client, two_tank_csv):
    ds = client.upload(two_tank_csv, **IO)
    run = dict(r=1e-3, p0=[0, 0, 0, 0, 0, 0], end_sample=50)
    truth = [10, 5, 0.0791, 0.1342]
    job = client.submit_smoothing("two_tank", ds, params=truth, **run)
    assert list(client.job(job.id).proto.smoothing.theta0) == truth
    given = job.result()
    as_text = client.smooth("two_tank", ds, params="10,5,0.0791,0.1342", **run)
    np.testing.assert_array_equal(as_text.to_frame().to_numpy(), given.to_frame().to_numpy())
    # A job: its estimate, as the CLI's --params takes it.
    job = client.submit_identification("two_tank", ds, passes=2, theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10],
                                       r=1e-3)
    res = job.result()
    smoothed = client.submit_smoothing("two_tank", ds, params=job, **run)
    spec = client.job(smoothed.id).proto.smoothing
    assert list(spec.theta0) == res.theta.tolist()
    final = client.submit_smoothing("two_tank", ds, params=job.id, estimate="final", **run)
    assert list(client.job(final.id).proto.smoothing.theta0) == res.theta_final.tolist()
    with pytest.raises(TypeError, match="params or theta0"):
        client.smooth("two_tank", ds, params=truth, theta0=truth, **run)
    with pytest.raises(ValueError, match="not one"):
        client.smooth("two_tank", ds, params=truth, estimate="final", **run)


def test_a_smoothing_result_summarises_and_plots(client, two_tank_csv, tmp_path):
    ds = client.upload(two_tank_csv, **IO)
    res = client.smooth("two_tank", ds, params=[10, 5, 0.0791, 0.1342], r=1e-3, end_sample=200,
                        p0=[1e-4, 1e-4, 1, 1, 1e-6, 1e-6])
    frame, filtered = res.to_frame(), res.filtered()
    summary = res.summary()
    assert list(summary.index) == res.names == ["h1", "h2", "A1", "A2", "k1", "k2"]
    assert summary.loc["A1", "first"] == frame["A1"].iloc[0]
    assert summary.loc["k2", "std_last"] == frame["std.k2"].iloc[-1]
    # At the last sample the smoother has nothing later to add: the filter's estimate.
    np.testing.assert_array_equal(summary["last"].to_numpy(), summary["filtered_last"].to_numpy())
    # Earlier, it knows more than the filter did then.
    assert (frame["std.A1"].iloc[0] < filtered["std.A1"].iloc[0])
    fig = res.plot(tmp_path / "smoothed.png")
    assert [ax.get_ylabel() for ax in fig.axes] == res.names
    np.testing.assert_array_equal(fig.axes[2].lines[1].get_ydata(), frame["A1"].to_numpy())
    np.testing.assert_array_equal(fig.axes[2].lines[0].get_ydata(), filtered["A1"].to_numpy())
    assert (tmp_path / "smoothed.png").read_bytes().startswith(b"\x89PNG")


def test_validate_fits_the_initial_states_it_is_told(client, two_tank_csv):
    ds = client.upload(two_tank_csv, **IO)
    truth = [10, 5, 0.0791, 0.1342]
    fit = client.validate("two_tank", ds, truth, x0=[0.1, 0.1], estimate_x0=True, x0_samples=200)
    spec = client.job(fit.job_id).proto.validation
    assert list(spec.initial_state.estimate) == ["all"] and spec.estimate_x0_samples == 200
    # From a wrong start, the states fitted on 200 samples: the record simulated as it was made.
    assert (fit.fits["fit_percent"] > 99).all(), fit.fits
    given = client.validate("two_tank", ds, "10,5,0.0791,0.1342", x0=[0.1, 0.1])
    assert (given.fits["fit_percent"] < fit.fits["fit_percent"]).all()
