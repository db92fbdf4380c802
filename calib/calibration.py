"""A fitted calibration: model, parameters with standard errors, fit statistics and provenance.

The file states its equation in keys a program reads, so that no one has to guess a convention:
`equation` (calib/equations.py EQUATIONS, in the parameters' own names), `tau` (`absolute_c`: tau is the
DUT temperature in degC as measured; `not_used`), and `tau_0_c` only where the equation itself subtracts
a constant from tau. The centre a solve used internally (`temp_ref_c` in memory; it changes rounding, not
the field) is `solve_centre_c`: not part of the equation, never to be applied. Files of format version 1
(a top-level `temp_ref_c`) still load.

Format version 3 states the measurand beside the equation, so that firmware can act on the file alone
(docs/calibration-file.md): `reading` (how h was made from the device: its identity, SET/RESET mode, raw
unit and the conversion from its output codes, the driver's settings, the readings averaged into one h),
`tau_source` (the thermometer that gave tau), `frame` (of B and of h), `indexing` (calib/equations.py
INDEXING: one convention for every parameter name) and `reference_chain` (whether the reference field
rests on a commissioned reference). calib states what it is given (rig/analysis/measurand.py makes them);
a key nobody stated is null, and `missing_measurand()` says in words what a file lacks (files of versions
1 and 2 lack them all).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field

import numpy as np

from calib.equations import (
    INDEXING,
    MODELS,
    OPTIONAL_PARAMS,
    PARAM_SHAPES,
    RENAMED_PARAMS,
    apply,
    equation_of,
    parameter_labels,
    renamed,
    renamed_label,
    tau_convention,
)
from calib.errors import DataError

FORMAT_NAME = "magrig-calibration"
# 2: `equation`, `tau`, `tau_0_c` / `solve_centre_c` instead of `temp_ref_c`; 3: the measurand (module doc),
# P12's raw offset `h0_nt` (was `b_nt`)
FORMAT_VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
TAU_0_KEY = "tau_0_c"  # the constant an equation subtracts from tau (named in the equation)
SOLVE_CENTRE_KEY = "solve_centre_c"  # internal to the solve: not part of the equation
# the measurand's keys (format version 3), each with the words that say what a file without it lacks
MEASURAND = {
    "reading": "how h was read from the device (reading:)",
    "tau_source": "the thermometer that gave tau (tau_source:)",
    "frame": "the frames of B and h (frame:)",
    "indexing": "the parameters' index convention (indexing:)",
    "reference_chain": "what the reference field rests on (reference_chain:)",
}
READING_MODES = ("set_reset_pair", "set_only", "single", "not_stated")
MAGNITUDES_KEY = "magnitude_range_nt"  # stats: {h: [lo, hi], B: [lo, hi]} of the rows used


def _utc_now() -> str:
    return dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


@dataclass
class Calibration:
    """Result of a fit. `params` and `std_errors` share keys (see calib.models.registry for names and
    shapes)."""

    model: str
    params: dict[str, np.ndarray]
    std_errors: dict[str, np.ndarray]
    temp_ref_c: float | None = None
    stats: dict = field(default_factory=dict)
    source: dict = field(default_factory=dict)
    software_version: str = "unknown"  # the caller states it: calib does not know who packaged it
    created_utc: str = field(default_factory=_utc_now)
    # the uncertainty budget (calib/uncertainty/montecarlo.py Budget.as_dict): expanded uncertainties with the
    # keys and shapes of `params`, and each input's contribution; None when it was not evaluated
    uncertainty: dict | None = None
    # per-row flags of a robust fit (True = flagged as outlier); not saved in the calibration file
    outliers: np.ndarray | None = field(default=None, repr=False, compare=False)
    # the measurand (module doc); None: not stated
    reading: dict | None = None
    tau_source: dict | None = None
    frame: dict | None = None
    indexing: dict | None = field(default_factory=lambda: dict(INDEXING))
    reference_chain: dict | None = None
    format_version: int = FORMAT_VERSION  # of the file it was read from (a new calibration: this one's)

    def apply(self, h_nt: np.ndarray, temp_c: np.ndarray | None = None) -> np.ndarray:
        """Calibrated field B (N,3) in nT for raw readings h (N,3) in nT."""
        return apply(self.model, self.params, np.atleast_2d(h_nt), temp_c, self.temp_ref_c)

    def to_dict(self) -> dict:
        """Plain python types only (lists, floats, str), so YAML/JSON round-trip exactly."""
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "model": self.model,
            **self.equation_keys(),
            **{key: to_plain(getattr(self, key)) for key in MEASURAND},
            "params": {k: np.asarray(v, float).tolist() for k, v in self.params.items()},
            "std_errors": {k: np.asarray(v, float).tolist() for k, v in self.std_errors.items()},
            "stats": to_plain(self.stats),
            "source": to_plain(self.source),
            "software_version": self.software_version,
            "created_utc": self.created_utc,
            **({} if self.uncertainty is None else {"uncertainty": to_plain(self.uncertainty)}),
        }

    def equation_keys(self) -> dict:
        """`equation`, `tau` and the temperature constant in the key that says what it is (module doc)."""
        equation = equation_of(self.model, self.params)
        out = {"equation": equation, "tau": tau_convention(self.model, self.params)}
        if TAU_0_KEY in equation:
            out[TAU_0_KEY] = float(self.temp_ref_c or 0.0)  # what apply() subtracts
        elif self.temp_ref_c is not None:
            out[SOLVE_CENTRE_KEY] = float(self.temp_ref_c)
        return out

    def missing_measurand(self) -> list[str]:
        """What the file does not state of its measurand, one plain phrase each ([] for a whole one): the
        measurand's keys (files before version 3 have none), the field magnitudes it was calibrated at
        (`rig apply` checks rows against them), and, for a session's file before version 3, a source hash
        taken of the session as its run closed it."""
        out = [words for key, words in MEASURAND.items() if getattr(self, key) is None]
        if MAGNITUDES_KEY not in self.stats:
            out.append(f"the field magnitudes it was calibrated at (stats.{MAGNITUDES_KEY})")
        if self.format_version < 3 and self.source.get("kind") == "session":
            out.append("a source.sha256 of the session as its run closed it (before version 3 a run's "
                       "files hashed the session while it was still being written)")
        return out

    @classmethod
    def from_dict(cls, d: object, where: str = "calibration") -> Calibration:
        """Validate and build; a problem raises DataError naming `where` and the key path."""
        if not isinstance(d, dict):
            raise DataError(f"{where}: not a calibration (expected a mapping at the top level)")
        if d.get("format", FORMAT_NAME) != FORMAT_NAME:
            raise DataError(f"{where}: key 'format' is {d.get('format')!r}, expected {FORMAT_NAME!r}")
        model = d.get("model")
        if model not in MODELS:
            raise DataError(f"{where}: key 'model' is {model!r}, expected one of {', '.join(MODELS)}")
        version = d.get("format_version", FORMAT_VERSION)
        if version not in READABLE_VERSIONS:
            raise DataError(f"{where}: key 'format_version' is {version!r}; this magrig reads "
                            f"{', '.join(map(str, READABLE_VERSIONS))}")
        d = _with_current_names(d, model)
        params = _read_arrays(d, "params", model, where)
        std_errors = _read_arrays(d, "std_errors", model, where, required=set(params))
        temp_ref = _read_centre(d, model, params, where, legacy=version == 1)
        for key in ("stats", "source"):
            if not isinstance(d.get(key, {}), dict):
                raise DataError(f"{where}: key {key!r} must be a mapping")
        measurand = _read_measurand(d, where)
        return cls(
            model=model,
            params=params,
            std_errors=std_errors,
            temp_ref_c=None if temp_ref is None else float(temp_ref),
            stats=d.get("stats", {}),
            source=d.get("source", {}),
            software_version=str(d.get("software_version", "unknown")),
            created_utc=str(d.get("created_utc", "")),
            uncertainty=_read_uncertainty(d, params, where),
            format_version=version,
            **measurand,
        )


def _with_current_names(d: dict, model: str) -> dict:
    """The file's content with every parameter under its current name (RENAMED_PARAMS: P12's `b_nt` is
    `h0_nt`), in `params`, `std_errors`, the uncertainty's per-parameter tables and the covariance's labels,
    and its equation as this model states it with that name. A file that gives both names is left as it is
    (and refused for the unknown one)."""
    old_names = RENAMED_PARAMS.get(model, {})
    params = d.get("params")
    if not old_names or not isinstance(params, dict) or not any(old in params for old in old_names):
        return d
    if any(new in params for new in old_names.values()):
        return d

    def table(block):
        return {renamed(model, k): v for k, v in block.items()} if isinstance(block, dict) else block

    out = {**d, "params": table(params), "std_errors": table(d.get("std_errors"))}
    equation = d.get("equation")
    if isinstance(equation, str):
        for old, new in old_names.items():
            equation = equation.replace(f"(h - {old})", f"(h - {new})")
        out["equation"] = equation
    u = d.get("uncertainty")
    if isinstance(u, dict):
        per_parameter = ("expanded", "coverage_factors", "effective_dof", "interval")
        u = {**u, **{key: table(u[key]) for key in per_parameter if key in u}}
        cov = u.get("covariance")
        if isinstance(cov, dict) and isinstance(cov.get("parameters"), list):
            u["covariance"] = {**cov, "parameters": [renamed_label(model, str(x)) for x in cov["parameters"]]}
        out["uncertainty"] = u
    return out


def _read_measurand(d: dict, where: str) -> dict:
    """The measurand's keys (MEASURAND), each a mapping or null; `reading.mode` one of READING_MODES and
    `reference_chain.traceable` true or false where they are given. A file before version 3 has none: all
    None, which `missing_measurand` says."""
    out = {}
    for key in MEASURAND:
        value = d.get(key)
        if value is not None and not isinstance(value, dict):
            raise DataError(f"{where}: key {key!r} must be a mapping or null")
        out[key] = value
    mode = (out["reading"] or {}).get("mode")
    if out["reading"] is not None and mode not in READING_MODES:
        raise DataError(f"{where}: key 'reading.mode' is {mode!r}, expected one of "
                        f"{', '.join(READING_MODES)}")
    chain = out["reference_chain"]
    if chain is not None and not isinstance(chain.get("traceable"), bool):
        raise DataError(f"{where}: key 'reference_chain.traceable' must be true or false")
    return out


def _read_centre(d: dict, model: str, params: dict, where: str, legacy: bool) -> float | None:
    """The temperature constant (tau_0_c, solve_centre_c, or a version 1 file's temp_ref_c), after checking
    that the stated equation and tau convention are the ones this model applies: a file that says
    otherwise would be applied differently from what it claims."""
    equation = equation_of(model, params)
    for key, expected in (("equation", equation), ("tau", tau_convention(model, params))):
        if key in d and d[key] != expected:
            raise DataError(f"{where}: key {key!r} is {d[key]!r}, but a {model} calibration with these "
                            f"parameters applies {expected!r}")
    given = [k for k in (TAU_0_KEY, SOLVE_CENTRE_KEY, "temp_ref_c") if d.get(k) is not None]
    if len(given) > 1:
        raise DataError(f"{where}: keys {' and '.join(map(repr, given))} both given; a file states one")
    if not given:
        if TAU_0_KEY in equation and legacy:
            return 0.0  # how version 1 applied a missing temp_ref_c
        if TAU_0_KEY in equation:
            raise DataError(f"{where}: key {TAU_0_KEY!r} is missing (the equation subtracts it from tau)")
        return None
    value = d[given[0]]
    if not _is_number(value):
        raise DataError(f"{where}: key {given[0]!r} must be a number, got {value!r}")
    if given[0] == SOLVE_CENTRE_KEY and TAU_0_KEY in equation:
        raise DataError(f"{where}: key {SOLVE_CENTRE_KEY!r} given, but this equation needs {TAU_0_KEY!r}")
    return float(value)


def standard_uncertainty(section: dict, name: str) -> np.ndarray:
    """A parameter's standard uncertainty from a checked `uncertainty:` section: its expanded U over its
    own coverage factor (`coverage_factors`, from its effective degrees of freedom), else the section's."""
    k = (section.get("coverage_factors") or {}).get(name, section["coverage_factor"])
    return np.asarray(section["expanded"][name], float) / np.asarray(k, float)


def _read_uncertainty(d: dict, params: dict, where: str) -> dict | None:
    """The `uncertainty` section, checked: a coverage factor, `expanded` with the keys and shapes of
    `params` (finite, not negative), a `budget` list of {source, contribution_nt}."""
    block = d.get("uncertainty")
    if block is None:
        return None
    if not isinstance(block, dict):
        raise DataError(f"{where}: key 'uncertainty' must be a mapping")
    if not _is_number(block.get("coverage_factor")) or block["coverage_factor"] <= 0:
        raise DataError(f"{where}: key 'uncertainty.coverage_factor' must be a positive number")
    expanded = block.get("expanded")
    if not isinstance(expanded, dict):
        raise DataError(f"{where}: key 'uncertainty.expanded' is missing or not a mapping")
    for name, value in params.items():
        if name not in expanded:
            raise DataError(f"{where}: key 'uncertainty.expanded.{name}' is missing")
        try:
            arr = np.array(expanded[name], dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"{where}: key 'uncertainty.expanded.{name}' is not numeric") from None
        if arr.shape != np.shape(value) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise DataError(f"{where}: key 'uncertainty.expanded.{name}' must have shape {np.shape(value)} "
                            "and finite, non-negative values")
    factors = block.get("coverage_factors")
    if factors is not None and not isinstance(factors, dict):
        raise DataError(f"{where}: key 'uncertainty.coverage_factors' must be a mapping")
    for name, value in (factors or {}).items():
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            arr = np.array(np.nan)
        if name not in params or arr.shape != np.shape(params[name]) or not np.all(np.isfinite(arr)) \
                or np.any(arr <= 0):
            raise DataError(f"{where}: key 'uncertainty.coverage_factors.{name}' must be a parameter's name "
                            "with positive numbers in its shape")
    field_dof = block.get("field_effective_dof")
    if field_dof is not None and (not _is_number(field_dof) or field_dof <= 0):
        raise DataError(f"{where}: key 'uncertainty.field_effective_dof' must be a positive number or null")
    budget = block.get("budget", [])
    if not isinstance(budget, list) or not all(
            isinstance(b, dict) and isinstance(b.get("source"), str) and _is_number(b.get("contribution_nt"))
            for b in budget):
        raise DataError(f"{where}: key 'uncertainty.budget' must be a list of {{source, contribution_nt}}")
    _check_covariance(block.get("covariance"), params, where)
    size_u = block.get("expanded_norm_error_nt")
    if size_u is not None and (not _is_number(size_u) or size_u < 0):
        raise DataError(f"{where}: key 'uncertainty.expanded_norm_error_nt' must be a finite, non-negative "
                        "number")
    for key in ("model_error_nt", "hysteresis_state_nt"):
        per_axis = block.get(key)
        if per_axis is not None and (not isinstance(per_axis, list) or len(per_axis) != 3 or not all(
                _is_number(v) and v >= 0 for v in per_axis)):
            raise DataError(f"{where}: key 'uncertainty.{key}' must be 3 finite, non-negative numbers")
    return block


def _check_covariance(cov, params: dict, where: str) -> None:
    """`uncertainty.covariance` (optional: files from before it was written have none): {parameters: the
    flat parameter labels in order, matrix: P x P, finite and symmetric}."""
    if cov is None:
        return
    labels = parameter_labels(params)
    if not isinstance(cov, dict) or cov.get("parameters") != labels:
        raise DataError(f"{where}: key 'uncertainty.covariance.parameters' must list the parameters in "
                        f"order: {', '.join(labels[:3])}, ...")
    try:
        matrix = np.array(cov.get("matrix"), dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{where}: key 'uncertainty.covariance.matrix' is not numeric") from None
    size = len(labels)
    if matrix.shape != (size, size) or not np.all(np.isfinite(matrix)) or not _symmetric(matrix):
        raise DataError(f"{where}: key 'uncertainty.covariance.matrix' must be a finite, symmetric "
                        f"{size}x{size} matrix")


def _symmetric(matrix: np.ndarray) -> bool:
    """Symmetric to rounding, on the scale of each element's own variances (sqrt(c_ii c_jj)): parameters
    in units far apart (1e-8 /degC beside 1e5 nT) must not make one element's rounding look large."""
    scale = np.sqrt(np.outer(np.abs(np.diag(matrix)), np.abs(np.diag(matrix))))
    return bool(np.all(np.abs(matrix - matrix.T) <= 1e-9 * scale + 1e-300))


def _is_number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and np.isfinite(x)


def _read_arrays(d: dict, section: str, model: str, where: str, required: set | None = None) -> dict:
    block = d.get(section)
    if not isinstance(block, dict):
        raise DataError(f"{where}: key {section!r} is missing or not a mapping")
    shapes = {**PARAM_SHAPES[model], **OPTIONAL_PARAMS[model]}
    needed = set(PARAM_SHAPES[model]) if required is None else required
    for name in [k for k in shapes if k in needed]:
        if name not in block:
            raise DataError(f"{where}: key '{section}.{name}' is missing (model {model})")
    out = {}
    for name, value in block.items():
        if name not in shapes:
            raise DataError(f"{where}: key '{section}.{name}' is not a parameter of model {model}")
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"{where}: key '{section}.{name}' is not numeric") from None
        if arr.shape != shapes[name]:
            raise DataError(f"{where}: key '{section}.{name}' has shape {arr.shape}, expected {shapes[name]}")
        if not np.all(np.isfinite(arr)):
            raise DataError(f"{where}: key '{section}.{name}' contains NaN or inf")
        out[name] = arr
    return out


def to_plain(x: object) -> object:
    """Numpy scalars/arrays and tuples to python floats/ints/lists; dict keys to str."""
    if isinstance(x, dict):
        return {str(k): to_plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [to_plain(v) for v in x]
    if isinstance(x, np.ndarray):  # tolist() gives python numbers already, except of an object array
        return x.tolist() if x.dtype != object else to_plain(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return x
