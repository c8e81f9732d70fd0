"""Uploads from files, DataFrames and arrays, read back exactly."""
import os

import numpy as np
import pandas as pd
import pytest

import riccati
from conftest import DATA


def _reference():
    return pd.read_csv(os.path.join(DATA, "two_tank.csv"), float_precision="round_trip")


def test_a_csv_file_reads_back_bit_for_bit(client, two_tank_csv):
    ds = client.upload(two_tank_csv, inputs=["F1", "F2"], outputs=["h1", "h2"])
    assert isinstance(ds, riccati.Dataset) and ds.id
    assert ds.samples == 2000 and ds.input_names == ["F1", "F2"] and ds.output_names == ["h1", "h2"]
    back = client.dataset_data(ds)
    ref = _reference()
    np.testing.assert_array_equal(back.index.to_numpy(), ref["t"].to_numpy())
    np.testing.assert_array_equal(back.to_numpy(), ref[["F1", "F2", "h1", "h2"]].to_numpy())
    assert client.dataset(ds.id).name == "two_tank.csv"


def test_a_dataframe_and_arrays_are_uploaded_exactly(client):
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.1, 1.0, 50))
    u = rng.normal(size=(50, 1)) / 3.0
    y = rng.normal(size=(50, 2)) * 1e-7
    frame = pd.DataFrame({"time": t, "F": u[:, 0], "a": y[:, 0], "b": y[:, 1]})
    ds = client.upload(frame, inputs=["F"], outputs=["a", "b"], time="time")
    back = client.dataset_data(ds)
    np.testing.assert_array_equal(back.index.to_numpy(), t)
    np.testing.assert_array_equal(back.to_numpy(), np.column_stack([u, y]))
    # Indexed by time, as to_frame() and dataset_data() give it.
    ds2 = client.upload(back, inputs=["F"], outputs=["a", "b"])
    np.testing.assert_array_equal(client.dataset_data(ds2).to_numpy(), back.to_numpy())
    ds3 = client.upload((t, u[:, 0], y), inputs=["F"], outputs=["a", "b"])
    assert ds3.input_names == ["F"] and ds3.output_names == ["a", "b"]
    np.testing.assert_array_equal(client.dataset_data(ds3).to_numpy(), back.to_numpy())


def test_data_without_a_time_column_takes_a_sample_time(client, tmp_path):
    ref = _reference()
    untimed = tmp_path / "untimed.csv"
    ref[["F1", "F2", "h1", "h2"]].to_csv(untimed, index=False, float_format="%.17g")
    ds = client.upload(str(untimed), inputs=["F1", "F2"], outputs=["h1", "h2"], ts=4.0)
    back = client.dataset_data(ds)
    np.testing.assert_array_equal(back.index.to_numpy(), 4.0 * np.arange(len(ref)))
    np.testing.assert_array_equal(back.to_numpy(), ref[["F1", "F2", "h1", "h2"]].to_numpy())
    frame = ref[["F1", "F2", "h1", "h2"]].head(10)
    ds2 = client.upload(frame, inputs=["F1", "F2"], outputs=["h1", "h2"], ts=0.5)
    np.testing.assert_array_equal(client.dataset_data(ds2).index.to_numpy(), 0.5 * np.arange(10))
    with pytest.raises(ValueError, match="ts must be a positive sample time"):
        client.upload(frame, inputs=["F1", "F2"], outputs=["h1", "h2"], ts=-1)


def test_true_parameters_are_kept_with_the_dataset_and_checked(client):
    truth = {"A1": 10.0, "A2": 5.0, "k1": 0.0791, "k2": 0.1342}
    ds = client.upload(os.path.join(DATA, "two_tank.csv"), inputs=["F1", "F2"], outputs=["h1", "h2"],
                       true_parameters=truth)
    assert ds.true_parameters == truth
    assert client.dataset(ds.id).true_parameters == truth
    assert client.upload(os.path.join(DATA, "two_tank.csv"), inputs=["F1", "F2"],
                         outputs=["h1", "h2"]).true_parameters == {}
    with pytest.raises(riccati.InvalidArgument, match="not a finite number"):
        client.upload(os.path.join(DATA, "two_tank.csv"), inputs=["F1", "F2"], outputs=["h1", "h2"],
                      true_parameters={"A1": float("nan")})
    with pytest.raises(riccati.InvalidArgument, match="is not a parameter name"):
        client.upload(os.path.join(DATA, "two_tank.csv"), inputs=["F1", "F2"], outputs=["h1", "h2"],
                      true_parameters={"A 1": 10.0})


def test_a_mat_file(client):
    ds = client.upload(os.path.join(DATA, "two_tank.mat"), inputs=["F1", "F2"], outputs=["h1", "h2"])
    back = client.dataset_data(ds)
    np.testing.assert_array_equal(back.to_numpy(), _reference()[["F1", "F2", "h1", "h2"]].to_numpy())


def test_a_bad_upload_is_refused_with_where(client, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u,y\n0,1,2\n1,1,x\n")
    with pytest.raises(riccati.InvalidArgument) as e:
        client.upload(str(bad), inputs=["u"], outputs=["y"])
    assert "line 3" in e.value.message
    with pytest.raises(ValueError, match="no column 'z'"):
        client.upload(pd.DataFrame({"t": [0.0, 1.0], "u": [1.0, 2.0]}), inputs=["u"], outputs=["z"])
    with pytest.raises(riccati.NotFound):
        client.dataset("ds-does-not-exist")
