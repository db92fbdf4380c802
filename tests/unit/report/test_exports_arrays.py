"""C header / JSON / CSV exports from plain parameter arrays (no calibration object needed)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rig.core.errors import DataError
from rig.report.exports import c_header, c_identifier, csv_export, inverse_form, json_export, t24_form
from tests.unit.report.ccheck import max_relative_error, run_header


def _t24_params(rng):
    S = np.eye(3) + rng.normal(0, 0.02, (3, 3))
    K = rng.normal(0, 2e-4, (3, 3))
    b = rng.normal(0, 400, 3)
    kb = rng.normal(0, 5, 3)
    return S, K, b, kb


def _samples(rng, n=40):
    return rng.normal(0, 40000, (n, 3)), rng.uniform(-40, 80, n)


def test_t24_form_matches_the_model_equation():
    rng = np.random.default_rng(3)
    S, K, b, kb = _t24_params(rng)
    h, t = _samples(rng)
    want = np.array([(S + ti * K) @ hi + b + ti * kb for hi, ti in zip(h, t, strict=True)])
    np.testing.assert_allclose(t24_form(S, K, b, kb).apply(h, t), want, rtol=1e-12)


def test_t24_header_compiles_and_matches(tmp_path):
    rng = np.random.default_rng(4)
    S, K, b, kb = _t24_params(rng)
    h, t = _samples(rng)
    form = t24_form(S, K, b, kb)
    text = c_header(form, name="dut-1", source_sha256="ab" * 32)
    got = run_header(text, "dut-1", h, t, tmp_path)
    want = np.array([(S + ti * K) @ hi + b + ti * kb for hi, ti in zip(h, t, strict=True)])
    assert max_relative_error(got, want) < 1e-12


def test_p12_header_inverts_the_sensor_model(tmp_path):
    rng = np.random.default_rng(5)
    M = np.tril(np.eye(3) + rng.normal(0, 0.03, (3, 3)))  # h = M B + b
    b = rng.normal(0, 300, 3)
    field = rng.normal(0, 40000, (30, 3))
    h = field @ M.T + b
    text = c_header(inverse_form("p12", np.linalg.inv(M), b), name="p12dut")
    got = run_header(text, "p12dut", h, np.full(30, 25.0), tmp_path)
    assert max_relative_error(got, field) < 1e-9
    assert "temp_c is ignored" in text


def test_scalar_header_with_temperature_terms(tmp_path):
    rng = np.random.default_rng(6)
    A0, A1 = np.eye(3) + rng.normal(0, 0.02, (3, 3)), rng.normal(0, 1e-4, (3, 3))
    c0, c1 = rng.normal(0, 300, 3), rng.normal(0, 3, 3)
    form = inverse_form("scalar", A0, c0, A1, c1, tau_0_c=20.0)
    h, t = _samples(rng)
    want = np.array([(A0 + (ti - 20) * A1) @ (hi - c0 - (ti - 20) * c1) for hi, ti in zip(h, t, strict=True)])
    np.testing.assert_allclose(form.apply(h, t), want, rtol=1e-12)
    got = run_header(c_header(form, name="s"), "s", h, t, tmp_path)
    assert max_relative_error(got, want) < 1e-12


def test_header_has_guards_and_provenance():
    text = c_header(
        t24_form(*_t24_params(np.random.default_rng(0))), name="7 x", source_sha256="f00d", version="9.9"
    )
    assert "#ifndef MAGRIG_CAL_7_X_H" in text and "#endif /* MAGRIG_CAL_7_X_H */" in text
    assert "source sha256: f00d" in text and "magrig 9.9" in text and "model: t24" in text
    assert c_identifier("7 x") == "cal_7_x"


def test_non_finite_parameter_is_refused():
    S, K, b, kb = _t24_params(np.random.default_rng(0))
    b[1] = np.nan
    with pytest.raises(DataError, match="not finite"):
        c_header(t24_form(S, K, b, kb), name="x")


def test_wrong_shape_is_refused():
    with pytest.raises(DataError, match="3x3"):
        t24_form(np.eye(2), np.zeros((3, 3)), np.zeros(3), np.zeros(3))


def test_json_and_csv_round_trip_values():
    S, K, b, kb = _t24_params(np.random.default_rng(1))
    params = {"S": S, "K": K, "b_nt": b, "kb_nt_per_c": kb}
    errors = {"S": np.full((3, 3), 1e-5), "b_nt": np.array([1.0, 2.0, np.nan])}
    doc = json.loads(json_export(t24_form(S, K, b, kb), params, errors, {"model": "t24"}))
    np.testing.assert_array_equal(np.array(doc["params"]["S"]), S)
    assert doc["std_errors"]["b_nt"] == [1.0, 2.0, None]
    assert doc["flight_form"]["equation"] == "B = M(tau) h + o(tau)"
    rows = csv_export(params, errors, {"S": np.full((3, 3), 4e-5)}).splitlines()
    assert rows[0] == "parameter,value,std_error,expanded_uncertainty"
    assert len(rows) == 1 + 9 + 9 + 3 + 3
    s01 = next(r for r in rows if r.startswith("S[0][1],")).split(",")
    assert float(s01[1]) == S[0, 1] and float(s01[2]) == 1e-5 and float(s01[3]) == 4e-5
    assert next(r for r in rows if r.startswith("K[2][2],")).endswith(",,")  # no std error, no budget
