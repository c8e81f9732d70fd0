"""Filter sessions: step() and stream() against the same filter run as a job."""
import os

import numpy as np
import pandas as pd
import pytest

import riccati
from conftest import DATA

SETTINGS = dict(filter="ekf", x0="first", theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10], q=0, r=1e-3)


@pytest.fixture(scope="module")
def record():
    return pd.read_csv(os.path.join(DATA, "two_tank.csv"), float_precision="round_trip")


def test_a_stream_reproduces_the_first_pass_of_an_identification(client, record):
    res = client.identify("two_tank", os.path.join(DATA, "two_tank.csv"), inputs=["F1", "F2"],
                          outputs=["h1", "h2"], passes=1, **SETTINGS)
    with client.session("two_tank", batch=64, **SETTINGS) as s:
        estimates = list(s.stream(record))  # the model's input and output columns, by name
    assert len(estimates) == len(record)
    assert [e.sequence for e in estimates] == list(range(len(record)))
    last = estimates[-1]
    assert list(last.state.index) == ["h1", "h2", "A1", "A2", "k1", "k2"]
    # The same filter over the same samples: the pass's end, bit for bit.
    np.testing.assert_array_equal(last.state[["A1", "A2", "k1", "k2"]].to_numpy(), res.theta_final.to_numpy())
    # And the trace, sample by sample.
    trace = np.array([e.state[["A1", "A2", "k1", "k2"]].to_numpy() for e in estimates])
    np.testing.assert_array_equal(trace, res.traces.loc[1].to_numpy())


def test_step_and_stream_agree(client, record):
    rows = list(zip(record["t"], record[["F1", "F2"]].to_numpy(), record[["h1", "h2"]].to_numpy()))[:200]
    with client.session("two_tank", **SETTINGS) as a, client.session("two_tank", **SETTINGS) as b:
        stepped = [a.step(t, u, y) for t, u, y in rows]
        streamed = list(b.stream(rows, batch=37))
        assert a.refresh().info.measurements == 200
    for x, y in zip(stepped, streamed):
        assert x.t == y.t
        np.testing.assert_array_equal(x.state.to_numpy(), y.state.to_numpy())
        np.testing.assert_array_equal(x.innovation.to_numpy(), y.innovation.to_numpy())
    e = stepped[10]
    # The innovation is the measurement less the predicted output.
    np.testing.assert_allclose(e.innovation.to_numpy(), rows[10][2] - e.y_predicted.to_numpy(), rtol=0, atol=1e-15)


def test_a_refused_measurement_names_itself_and_the_session_goes_on(client, record):
    with client.session("two_tank", **SETTINGS) as s:
        s.step(0.0, [0.1, 0.03], [0.4, 0.15])
        with pytest.raises(riccati.MeasurementRefused) as e:
            s.step(0.0, [0.1, 0.03], [0.4, 0.15])  # t not after the last
        assert e.value.code.name == "INVALID_ARGUMENT" and e.value.sequence == 1
        with pytest.raises(riccati.MeasurementRefused):
            s.step(1.0, [0.1], [0.4, 0.15])  # one input short
        out = list(s.stream([(1.0, [0.1, 0.03], [0.4, 0.15]), (1.0, [0.1, 0.03], [0.4, 0.15]),
                             (2.0, [0.1, 0.03], [0.4, 0.15])], errors="yield"))
        assert [type(x).__name__ for x in out] == ["Estimate", "MeasurementRefused", "Estimate"]
        assert s.refresh().info.measurements == 3
    with pytest.raises(riccati.NotFound):
        client._call("session", client._sessions.GetSession, riccati.v1.sessions_pb2.GetSessionRequest(id=s.id))


def test_a_session_is_refused_with_its_reason(client):
    with pytest.raises(riccati.InvalidArgument) as e:
        client.session("two_tank", filter="ekf", r=1e-3, theta0=[1, 2, 3])
    assert "theta0" in e.value.message
