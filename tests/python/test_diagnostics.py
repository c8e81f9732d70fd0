"""Residual diagnostics in the Python client: a table per test named by the
model's outputs and inputs, with riccatid's p-values and degrees of freedom
(made up here, so that a client that recomputed them would differ)."""
import math

import numpy as np
from google.protobuf import text_format

import riccati
from riccati.v1 import jobs_pb2

MESSAGE = """
samples: 2000 lags: 20 band: 0.0438
ljung_box: [25.0, 40.0] ljung_box_limit: 31.41 ljung_box_dof: 20 ljung_box_p: [0.123, 0.00456]
cross_statistic: [10, 0, 50, 0] cross_limit: [32.67, 0, 32.67, 0]
cross_dof: [21, 0, 21, 0] cross_p: [0.777, 1, 0.000888, 1]
nis_mean: 2.3 nis_lower: 1.91 nis_upper: 2.09 nis_dof: 4000 nis_p: 0.00321
white: false uncorrelated_with_inputs: false nis_consistent: false
summary: "whiteness ..."
"""


def diagnostics(text=MESSAGE):
    return riccati.Diagnostics(text_format.Parse(text, jobs_pb2.Diagnostics()), ["h1", "h2"], ["F1", "valve"])


def test_each_test_has_names_statistic_limit_p_value_dof_and_verdict():
    d = diagnostics()
    assert d.whiteness.index.tolist() == ["h1", "h2"]
    assert d.whiteness.loc["h1"].tolist() == [25.0, 31.41, 0.123, 20, "pass"]
    assert d.whiteness.loc["h2", "p_value"] == 0.00456 and d.whiteness.loc["h2", "verdict"] == "fail"
    # Pairs (output, input) in the message's order, row i * nu + j.
    assert d.independence.index.tolist() == [("h1", "F1"), ("h1", "valve"), ("h2", "F1"), ("h2", "valve")]
    assert d.independence.loc[("h2", "F1")].tolist() == [50.0, 32.67, 0.000888, 21, "fail"]
    # A constant input: not tested, 0 dof, no p-value.
    constant = d.independence.loc[("h1", "valve")]
    assert constant["dof"] == 0 and math.isnan(constant["p_value"]) and constant["verdict"] == "pass"
    assert d.nis.loc["mean NIS"].tolist() == [2.3, 1.91, 2.09, 0.00321, 4000, "fail"]
    assert not d.passed and not d.white and d.summary == "whiteness ..."
    frame = d.to_frame()
    assert frame.columns.tolist() == ["test", "output", "input", "statistic", "limit", "p_value", "dof", "verdict"]
    assert frame["test"].tolist() == ["whiteness"] * 2 + ["independence"] * 4 + ["nis"]
    assert "valve" in repr(d) and "output 1" not in repr(d)


def test_without_nis_and_from_a_result_stored_before_p_values():
    old = text_format.Parse(MESSAGE, jobs_pb2.Diagnostics())
    for field in ("ljung_box_p", "ljung_box_dof", "cross_p", "cross_dof", "nis_dof", "nis_p"):
        old.ClearField(field)
    old.nis_mean = float("nan")
    d = riccati.Diagnostics(old, ["h1", "h2"], [])
    assert d.nis.empty
    assert np.isnan(d.whiteness["p_value"]).all() and np.isnan(d.whiteness["dof"]).all()
    # No input names given: numbered.
    assert d.independence.index.get_level_values("input").tolist() == ["u1", "u2", "u1", "u2"]
    assert d.independence["p_value"].isna().all()
