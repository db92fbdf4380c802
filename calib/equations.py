"""The calibration models as equations: each model's parameters (names and shapes, the contract of the
calibration file) and the calibrated field they give (parameters in, field out). No fitting here: the
fits (calib/models/t24.py, p12.py, scalar.py) and the registry that ties a model to its fit
(calib/models/registry.py) sit above this module, and calib/calibration.py uses it to apply and validate a
calibration.

- t24 (absolute-tau convention of the paper): B = (S + T K) h + b + T kb, T the DUT temperature in degC.
- t36 (same convention): B = (S + T K + T^2 K2) h + b + T kb + T^2 kb2, T24 with quadratic temperature terms.
- p12: h = Q P B + h0, so B = (Q P)^-1 (h - h0_nt). Q = diag(k); P lower-triangular with unit rows
  row 1 = (1, 0, 0), row 2 = (sin e1, cos e1, 0), row 3 = (sin e2 cos e3, sin e3, cos e2 cos e3):
  e1 tilts axis 2 towards axis 1, e2 tilts axis 3 towards axis 1, e3 tilts axis 3 towards axis 2.
- scalar: B = (A + t KA)(h - c - t kc), t = T - temp_ref_c (the file's tau_0_c). A (and KA)
  upper-triangular: the field comes out in a sensor-aligned frame (axis 1 along sensor axis 1, axis 2 in
  the sensor 1-2 plane), which is the true frame up to one unknown rotation. The temperature terms are
  optional.

No parameter name means two things across models: T24's `b_nt` is added to the field, P12's raw offset,
subtracted from h, is `h0_nt` (files that called it `b_nt` still load: RENAMED_PARAMS). Every parameter
element is named one way everywhere (the YAML, the covariance, the report, the certificate, the exports):
`parameter_label`, zero-based `[row][column]`, rows the output axes (INDEXING).
"""

from __future__ import annotations

import numpy as np

from calib.errors import DataError

# required parameters of each model and their shapes, in the order models are listed everywhere
PARAM_SHAPES: dict[str, dict[str, tuple[int, ...]]] = {
    "t24": {"S": (3, 3), "K": (3, 3), "b_nt": (3,), "kb_nt_per_c": (3,)},
    "p12": {"k": (3,), "angles_deg": (3,), "h0_nt": (3,)},
    "scalar": {"A": (3, 3), "c_nt": (3,)},
    "t36": {"S": (3, 3), "K": (3, 3), "K2": (3, 3), "b_nt": (3,), "kb_nt_per_c": (3,), "kb2_nt_per_c2": (3,)},
}
OPTIONAL_PARAMS: dict[str, dict[str, tuple[int, ...]]] = {
    "t24": {},
    "p12": {},
    "scalar": {"KA_per_c": (3, 3), "kc_nt_per_c": (3,)},
    "t36": {},
}
MODELS = tuple(PARAM_SHAPES)
# names older files gave a parameter, by model: {old: new}; a file is read with the new name
RENAMED_PARAMS: dict[str, dict[str, str]] = {"p12": {"b_nt": "h0_nt"}}

# The one index convention of every parameter element, as a calibration file states it (key `indexing`).
INDEXING = {
    "matrices": "M[row][column], zero-based; row = output axis of B (x, y, z), column = input axis of h",
    "vectors": "v[i], zero-based (x, y, z)",
    "flat_order": "row-major: S[0][0], S[0][1], ..., S[2][2], then the next parameter",
}


def parameter_label(name: str, index: tuple[int, ...] = ()) -> str:
    """One element's name: `S[0][1]` (row 0, column 1), `b_nt[2]`, `name` for a scalar; INDEXING."""
    return name + "".join(f"[{int(i)}]" for i in index)


def parameter_labels(params: dict) -> list[str]:
    """Every element's name in INDEXING's flat order (each parameter row-major, in the dict's order): the
    order of a covariance's rows and of every export's list."""
    return [parameter_label(name, idx) for name, value in params.items()
            for idx in np.ndindex(*np.shape(value))]


def renamed(model: str, name: str) -> str:
    """A parameter's current name for the name an older file gave it (RENAMED_PARAMS)."""
    return RENAMED_PARAMS.get(model, {}).get(name, name)


def renamed_label(model: str, label: str) -> str:
    """A flat label (`b_nt[2]`) with its parameter's current name (`h0_nt[2]` for P12)."""
    name, bracket, rest = label.partition("[")
    return renamed(model, name) + bracket + rest


def t24_regressors(h_nt, temp_c, temp_ref_c: float = 0.0) -> np.ndarray:
    """T24's regressors x = [1, t, h, t h] (N, 8), t = tau - temp_ref_c: the columns every output axis is
    linear in (the paper's Gram matrix is their sum of outer products)."""
    h = np.asarray(h_nt, float).reshape(-1, 3)
    t = np.broadcast_to(np.asarray(temp_c, float) - temp_ref_c, (h.shape[0],))
    return np.column_stack([np.ones(len(h)), t, h, t[:, None] * h])


def t36_regressors(h_nt, temp_c, temp_ref_c: float = 0.0) -> np.ndarray:
    """T36's regressors x = [1, t, t^2, h, t h, t^2 h] (N, 12), t = tau - temp_ref_c."""
    h = np.asarray(h_nt, float).reshape(-1, 3)
    t = np.broadcast_to(np.asarray(temp_c, float) - temp_ref_c, (h.shape[0],))
    t2 = t * t
    return np.column_stack([np.ones(len(h)), t, t2, h, t[:, None] * h, t2[:, None] * h])

# Each model's equation as its calibration file states it (key `equation`), in the file's own parameter
# names. tau is the DUT temperature in degC as measured (the file's `tau: absolute_c`); a constant an
# equation subtracts from it is named in the equation and stated beside it (`tau_0_c`). A model whose
# optional temperature terms change its equation has a second row, "<model> with temperature terms".
EQUATIONS: dict[str, str] = {
    "t24": "B = (S + tau K) h + b_nt + tau kb_nt_per_c",
    "t36": "B = (S + tau K + tau^2 K2) h + b_nt + tau kb_nt_per_c + tau^2 kb2_nt_per_c2",
    "p12": "B = inv(Q P) (h - h0_nt); Q = diag(k); P rows (1, 0, 0), (sin e1, cos e1, 0), "
           "(sin e2 cos e3, sin e3, cos e2 cos e3); (e1, e2, e3) = angles_deg",
    "scalar": "B = A (h - c_nt)",
    "scalar with temperature terms":
        "B = (A + (tau - tau_0_c) KA_per_c) (h - c_nt - (tau - tau_0_c) kc_nt_per_c)",
}
TAU_ABSOLUTE = "absolute_c"  # tau is the temperature in degC, not a difference from a reference
TAU_NOT_USED = "not_used"  # the equation has no temperature


def equation_of(model: str, params: dict) -> str:
    """The equation a calibration of `model` with these parameters applies (EQUATIONS)."""
    with_temperature = f"{model} with temperature terms"
    if with_temperature in EQUATIONS and needs_temperature(model, params):
        return EQUATIONS[with_temperature]
    return EQUATIONS[model]


def tau_convention(model: str, params: dict) -> str:
    return TAU_ABSOLUTE if needs_temperature(model, params) else TAU_NOT_USED


def needs_temperature(model: str, params: dict) -> bool:
    return model in ("t24", "t36") or (model == "scalar" and "KA_per_c" in params)


def p12_matrix(k: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """M = Q P, the lower-triangular matrix that maps the true field to the raw reading (without offset)."""
    e1, e2, e3 = np.radians(angles_deg)
    p = np.array(
        [
            [1.0, 0.0, 0.0],
            [np.sin(e1), np.cos(e1), 0.0],
            [np.sin(e2) * np.cos(e3), np.sin(e3), np.cos(e2) * np.cos(e3)],
        ]
    )
    return np.asarray(k, float)[:, None] * p


def p12_angles_from_rows(p: np.ndarray) -> np.ndarray:
    """Angles (deg) of a P whose rows 2 and 3 are unit vectors with positive last component."""
    e1 = np.arctan2(p[1, 0], p[1, 1])
    e3 = np.arcsin(np.clip(p[2, 1], -1.0, 1.0))
    e2 = np.arctan2(p[2, 0], p[2, 2])
    return np.degrees([e1, e2, e3])


def _t24_field(h, t, s, k, b, kb) -> np.ndarray:
    """(S + t K) h + b + t kb, one output column at a time over contiguous copies of the inputs' columns:
    no (N,3,3) temporary, and no BLAS call, which for an inner size of 3 spends more on waking its
    threads than on the sums. The result is an (N,3) view of a (3,N) array."""
    x = np.ascontiguousarray(h.T)
    t = np.ascontiguousarray(t)
    out = np.empty_like(x)
    for i in range(3):
        col = out[i]
        np.multiply(x[0], k[i, 0], out=col)
        col += x[1] * k[i, 1]
        col += x[2] * k[i, 2]
        col += kb[i]
        col *= t
        col += x[0] * s[i, 0]
        col += x[1] * s[i, 1]
        col += x[2] * s[i, 2]
        col += b[i]
    return out.T


def apply(model: str, params: dict, h_nt: np.ndarray, temp_c: np.ndarray | None, temp_ref_c: float | None):
    """Calibrated field (N,3) in nT from raw readings (N,3) in nT."""
    h = np.asarray(h_nt, dtype=float)
    if needs_temperature(model, params):
        if temp_c is None:
            raise DataError(f"a {model} calibration with temperature terms needs a temperature column (temp)")
        t = np.asarray(temp_c, dtype=float)[:, None]
    if model == "t24":
        return _t24_field(h, t[:, 0], params["S"], params["K"], params["b_nt"], params["kb_nt_per_c"])
    if model == "t36":
        linear = _t24_field(h, t[:, 0], params["S"], params["K"], params["b_nt"], params["kb_nt_per_c"])
        return linear + (t * t) * (h @ params["K2"].T + params["kb2_nt_per_c2"])
    if model == "p12":
        m = p12_matrix(params["k"], params["angles_deg"])
        return np.linalg.solve(m, (h - params["h0_nt"]).T).T
    if model == "scalar":
        if "KA_per_c" not in params:
            return (h - params["c_nt"]) @ params["A"].T
        dt = t - (temp_ref_c or 0.0)
        v = h - params["c_nt"] - dt * params["kc_nt_per_c"]
        return v @ params["A"].T + dt * (v @ params["KA_per_c"].T)
    raise DataError(f"unknown calibration model {model!r} (known: {', '.join(MODELS)})")
