"""What a calibration's model leaves out, as lines of its budget: the model checks' terms and the misfit.

    direction = thermal_direction(times, temps, history)       # +1 heating, -1 cooling, 0 unknown
    record_model_checks(cal, ds, direction)                    # cal.stats["model_checks"] (T24)
    sources, notes, noise, correction = model_sources(ds, cal, direction, weights)

What the parameters stand for: the T24 model that describes the DUT best over the calibration's fields
and temperatures, in its mean thermal state. A term T24 lacks then costs the calibrated field what T24
cannot follow of it, and a thermal hysteresis costs the parameters what the fit took from an unbalanced
history besides:

- The model checks (calib/checks/model_checks.py): T24 against T24 plus one deviation (a quadratic temperature
  term, a thermal hysteresis of the offset, a cubic field term). The terms the checks find (p < P_TERM) are
  fitted together with T24 (over a few temperature steps a curvature and a hysteresis share what the
  steps show: their estimates are correlated) and enter the budget as one source whose quantities are
  their coefficients, as u^2 + b^2 (the estimate b, uncorrected, a bias of unknown sign): a curvature or
  a cubic term moves the true field at the grid points by what a T24 fit over the grid cannot follow of
  it (calib.uncertainty.propagation InputSource.field_nt); the hysteresis moved the data by d_n c (d_n the
  thermal direction of each sample), which the parameters absorbed. At a point of use the DUT may be in either
  thermal state: +-c, a field error of its own ("thermal hysteresis state"). Another model's parameters
  (P12, the scalar fit, T36) absorb the hysteresis alike: their budgets take it as T24's checks find it
  in the same data; what else they cannot follow is in their own residual (the misfit).
- The misfit (rig/budget/misfit.py): the fit's residual (after those terms) beyond what the DUT's own
  noise explains, a field error at every grid point that no parameter carries. A stated uncertainty
  below the measured scatter is then impossible.
- The readings' noise and the offset's wander (rig/budget/wander.py) come from the residual of the
  model that follows the data best: this one's, or T24's with its checks' terms (P12's own holds what it
  cannot follow, which its misfit already states).

A hysteresis the checks find is corrected in the readings before any model is fitted
(rig/budget/hysteresis.py): it no longer biases the parameters. A linear fit's budget (T24, T36, P12)
then takes the correction's uncertainty along in its linearisation (`TermsFit.data_correction`,
calib/uncertainty/correction.py) and the terms' line leaves the hysteresis out; the scalar fit's keeps it, its
estimate fitted again on the corrected readings (about zero) with its u. The thermal state at a point of
use keeps the size the correction had.
"""

from __future__ import annotations

import numpy as np

from calib.checks.model_checks import FIELD_SCALE_NT, model_checks
from calib.equations import t24_regressors
from calib.uncertainty.correction import DataCorrection
from calib.uncertainty.propagation import InputSource
from rig.budget.misfit import everywhere, misfit_source, within_point_noise
from rig.budget.wander import wander_source

P_TERM = 1e-2  # a check whose p is below this puts its term in the budget
SIGNIFICANT = 3.0  # standard errors: a point-level error counts
THERMAL_PLAY_C = 1.0  # a temperature change beyond this reverses the thermal direction
# where the readings were corrected for the DUT's thermal hysteresis (rig/budget/hysteresis.py): the
# dataset's source holds d per axis (nT, in the field) and its u
CORRECTED, CORRECTED_U = "hysteresis_corrected_nt", "hysteresis_corrected_u_nt"
CARRIED = ("t24", "t36", "p12")  # models whose budgets take a hysteresis correction along (linear fits)
CHECK_TERMS = {"linearity in temperature": "temperature", "thermal hysteresis": "hysteresis",
               "linearity in the field": "field"}


def thermal_direction(times, temps, history=None, play_c: float = THERMAL_PLAY_C) -> np.ndarray:
    """(N,): +1 where the last temperature move beyond `play_c` before a sample was up, -1 down, 0 none
    yet; `history` ((t, temp_c) pairs, e.g. the session's temperature log) adds what came before and
    between the samples."""
    times, temps = np.asarray(times, float), np.asarray(temps, float)
    t_all, temp_all = times, temps
    if history:
        h = np.asarray(history, float).reshape(-1, 2)
        t_all, temp_all = np.r_[h[:, 0], times], np.r_[h[:, 1], temps]
    order = np.argsort(t_all, kind="stable")
    state, low, high = 0.0, np.inf, -np.inf
    seen = np.empty(len(order))
    for k in order:
        value = temp_all[k]
        low, high = min(low, value), max(high, value)
        if state >= 0 and value < high - play_c:
            state, low, high = -1.0, value, value
        elif state <= 0 and value > low + play_c:
            state, low, high = 1.0, value, value
        seen[k] = state
    return seen[len(t_all) - len(times):]


def record_model_checks(cal, ds, direction) -> None:
    """T24's model checks in the calibration's stats, for its budget and for acceptance."""
    cal.stats["model_checks"] = [c.as_dict() for c in model_checks(ds, direction)]


def _terms(kind: str, h, temp, direction, temp_mid: float) -> np.ndarray:
    """(N,3,k): the term's regressors per output axis (the same k per axis)."""
    n = len(h)
    if kind == "temperature":
        z = ((temp - temp_mid) ** 2)[:, None] * np.column_stack([h, np.ones(n)])  # (N,4)
        return np.repeat(z[:, None, :], 3, axis=1)
    if kind == "hysteresis":
        return np.repeat(np.asarray(direction, float).reshape(n, 1, 1), 3, axis=1)
    norm2 = np.sum(h * h, axis=1) / FIELD_SCALE_NT**2
    return (norm2[:, None] * h)[:, :, None]


def _checks(cal, ds, direction) -> dict[str, dict]:
    """T24's model checks by term (recorded in the stats, else made here: another model's data)."""
    checks = cal.stats.get("model_checks")
    if checks is None:
        checks = [c.as_dict() for c in model_checks(ds, direction)]
    return {CHECK_TERMS[c["name"]]: c for c in checks if c["name"] in CHECK_TERMS}


def _found(checks: dict[str, dict]) -> list[str]:
    """The terms the data show."""
    return [kind for kind, c in checks.items()
            if c.get("testable") and c.get("p") is not None and c["p"] < P_TERM]


def _joint_fit(x_base: np.ndarray, z: np.ndarray, ref: np.ndarray, w: np.ndarray):
    """Per output axis, ref_i on [x_base, z[:, i]] (rows weighted): (coefficients of z (3,k), their
    covariance for white noise (3,k,k), residuals (N,3), dof, the linear maps from ref_i to them (3,k,N))."""
    k = z.shape[2]
    coef, cov, resid = np.zeros((3, k)), np.zeros((3, k, k)), np.zeros_like(ref)
    maps = np.zeros((3, k, len(ref)))
    used = w > 0
    dof = int(used.sum()) - x_base.shape[1] - k
    for i in range(3):
        x = np.column_stack([x_base, z[:, i, :]])
        scale = np.linalg.norm(x[used], axis=0)
        scale[scale == 0] = 1.0
        xs = x[used] / scale
        u, s, vt = np.linalg.svd(xs * np.sqrt(w[used])[:, None], full_matrices=False)
        beta = (vt.T @ ((u.T @ (ref[used, i] * np.sqrt(w[used]))) / s)) / scale
        resid[:, i] = ref[:, i] - x @ beta
        sigma2 = float(np.sum(w[used] * resid[used, i] ** 2) / max(dof, 1))
        inv = (vt.T / s**2) @ vt / np.outer(scale, scale)
        first = x.shape[1] - k  # the terms' columns (none when k = 0)
        coef[i], cov[i] = beta[first:], sigma2 * inv[first:, first:]
        maps[i][:, used] = (((vt.T / s) @ u.T) * np.sqrt(w[used]) / scale[:, None])[first:]
    return coef, cov, resid, dof, maps


def model_sources(ds, cal, direction, weights=None,
                  step_reference_var=None):
    """(the budget's model-check sources (T24), its misfit and the offset's wander (rig/reference/
    wander.py); notes; for a model fitted to the reference vector, the readings' noise the fit's
    statistics should take (`_noise_and_wander`); the hysteresis correction the readings were given, as a
    linear fit's budget takes it along (calib/uncertainty/correction.py), or None). step_reference_var (3,):
    the variance of the reference's own error from one temperature step to the next (the ambient's scatter
    between its measurements), which the terms' estimates share with the offset's wander."""
    notes: list[str] = []
    w = np.ones(len(ds)) if weights is None else np.asarray(weights, float)
    points = ds.columns.get("point")
    fit = TermsFit(ds, cal, direction, w) if cal.model == "t24" else None
    # another model is judged against the fullest model of the DUT the data support (T24 with its checks'
    # terms): its parameters take the DUT's thermal hysteresis from an unbalanced history as T24's do, and
    # T24's residual shows the DUT's noise and wander without what this model cannot follow
    other = None if fit is not None or ds.ref_nt is None else TermsFit(ds, cal, direction, w)
    if fit is not None:
        resid, dof = fit.resid, fit.dof
    elif cal.model == "scalar":
        if ds.ref_nt is None:
            return [], ["misfit: the data have no reference field"], None, None
        field = cal.apply(ds.h_nt, ds.temp_c)
        resid = (np.linalg.norm(field, axis=1) - np.linalg.norm(ds.ref_nt, axis=1))[:, None]
        dof = int((w > 0).sum()) - sum(int(np.size(v)) for v in cal.params.values())
    else:
        resid = ds.ref_nt - cal.apply(ds.h_nt, ds.temp_c)
        dof = int((w > 0).sum()) - sum(int(np.size(v)) for v in cal.params.values()) // 3
    out: list[InputSource] = []
    misfit = misfit_source(resid, w, dof, points, notes, ds.ref_nt)
    # without a misfit line, this model's own residual is all that states what it cannot follow
    terms = fit if fit is not None else (other if misfit is not None else None)
    noise, step_var, t24_var = _noise_and_wander(ds, terms, resid, dof, w, out, notes)
    # a hysteresis corrected in the readings: a linear fit's budget takes the correction along
    correction = None if cal.model not in CARRIED or (fit or other) is None else \
        (fit or other).data_correction(direction, noise)
    carried = correction is not None
    if fit is not None:
        out = fit.sources(ds, cal, step_var, step_reference_var, notes, carried=carried) + out
    elif other is not None and "hysteresis" in other.found:
        if t24_var is None and points is not None:  # the estimate shares the steps with T24's wander
            t24_var = _wander(ds, other.resid, w)[2]
        out = other.sources(ds, cal, t24_var, step_reference_var, notes, hysteresis_only=True,
                            carried=carried) + out
    return out + ([misfit] if misfit is not None else []), notes, noise, correction


def _mean_square(resid: np.ndarray, w: np.ndarray, dof: int) -> float:
    used = w > 0
    return float(np.sum(w[used, None] * resid[used] ** 2) / max(dof, 1) / resid.shape[1])


def _wander(ds, resid: np.ndarray, w: np.ndarray):
    used = w > 0
    noise, _ = within_point_noise(resid[used], np.asarray(ds.columns["point"], object)[used])
    return wander_source(ds, resid, noise, w)


def _noise_and_wander(ds, terms, resid, dof, w, out: list, notes: list[str]):
    """(the readings' noise per axis for the fit's statistics (None: the fit's own residual), the offset
    wander's variance per step and axis, T24's) from the residual of the model that follows the data
    best: this model's or T24 with its checks' terms (`terms`), whichever is the smaller. A model that
    cannot follow the DUT's temperature terms (P12) leaves them in its residual, where they would pass for
    noise and, from one point to the next, for wander: its misfit line takes them, once. The offset's
    wander is appended to `out`. The noise is the residual's RMS, widened where the samples of a point
    share an error (`_clustered_noise`): the model sources take the rest of the residual."""
    points = ds.columns.get("point")
    base, base_dof = resid, dof
    if terms is not None and resid.shape[1] == 3 and \
            _mean_square(terms.resid, w, terms.dof) < _mean_square(resid, w, dof):
        base, base_dof = terms.resid, terms.dof
    if base.shape[1] != 3 or (terms is None and points is None):
        return None, None, None
    used = w > 0
    rms = np.sqrt(np.sum(w[used, None] * base[used] ** 2, axis=0) / max(base_dof, 1))
    if points is None:
        return rms, None, None
    wander, said, step_var = _wander(ds, base, w)
    notes += [] if wander is not None else [said]
    out += [] if wander is None else [wander]
    t24_var = step_var if terms is not None and base is terms.resid else None
    if terms is None and base is resid:
        return None, step_var, t24_var
    params = int(used.sum()) - base_dof
    noise = _clustered_noise(base[used], np.asarray(points, object)[used], rms, notes, params)
    return noise, step_var, t24_var


def _clustered_noise(resid: np.ndarray, points, rms: np.ndarray, notes: list[str],
                     params: int = 0) -> np.ndarray:
    """The noise the fit's statistics should take when the samples of one point share part of their error
    (a slow offset noise, anything fixed for a point): with n samples a point, an offset of variance s^2
    common to them weighs in the fit as a white noise of variance n s^2 does (the design effect: the
    samples of a point have the same regressors), so sqrt(sigma_w^2 + n s^2), sigma_w the scatter within
    points; s^2 the point means' variance beyond what sigma_w gives them, when SIGNIFICANT standard errors
    above zero (pooled over the axes). The point means are those of a fit's residual: `params` fitted per
    column took their share of the means' scatter (K points leave K - params of it). Else the residual's
    RMS (its white-noise reading)."""
    noise_w, _ = within_point_noise(resid, points)
    labels, index = np.unique(np.asarray(points).astype(str), return_inverse=True)
    counts = np.bincount(index, minlength=len(labels))
    if not np.all(np.isfinite(noise_w)) or len(labels) - params < 3:
        return rms
    sums = np.stack([np.bincount(index, resid[:, i], len(labels)) for i in range(3)], axis=1)
    means = sums / counts[:, None]
    kept = (len(labels) - params) / len(labels)
    excess = np.mean(means**2 / kept - noise_w**2 / counts[:, None], axis=1)  # per point, pooled over axes
    s2, se = float(np.mean(excess)), float(np.std(excess, ddof=1) / np.sqrt(len(excess)))
    if s2 <= SIGNIFICANT * se:
        return rms
    n = float(np.mean(counts))
    taken = np.sqrt(noise_w**2 + n * s2)
    notes.append(f"fit (statistical): the samples of a point share an error of {np.sqrt(s2):.1f} nT beyond "
                 f"their noise ({_fmt(noise_w)}) nT: taken as a noise of ({_fmt(taken)}) nT for the {n:.0f} "
                 "samples a point")
    return taken


class TermsFit:
    """T24 and the terms its checks found, fitted together (module docstring)."""

    def __init__(self, ds, cal, direction, w):
        self.checks = _checks(cal, ds, direction)
        self.found = _found(self.checks)
        # readings corrected for the hysteresis before the fit (rig/budget/hysteresis.py): the term is
        # fitted again, about zero, for the correction's uncertainty
        self.correction = None if CORRECTED not in ds.source else np.asarray(ds.source[CORRECTED], float)
        if self.correction is not None and direction is not None and "hysteresis" not in self.found:
            self.found.append("hysteresis")
        temps = np.asarray(ds.temp_c, float)
        self.mid = 0.5 * (float(temps.min()) + float(temps.max()))
        moving = np.asarray(direction, float) if direction is not None else np.zeros(len(ds))
        self.parts = [(kind, _terms(kind, ds.h_nt, temps, moving, self.mid)) for kind in self.found]
        self.z = (np.concatenate([p for _, p in self.parts], axis=2) if self.parts
                  else np.zeros((len(ds), 3, 0)))
        x_base = t24_regressors(ds.h_nt, ds.temp_c, self.mid if cal.temp_ref_c is None else cal.temp_ref_c)
        self.coef, self.cov, self.resid, self.dof, self.maps = _joint_fit(x_base, self.z, ds.ref_nt, w)

    def column(self, kind: str) -> int:
        """The first column of a term in `coef` and `cov`."""
        at = 0
        for name, z in self.parts:
            if name == kind:
                return at
            at += z.shape[2]
        raise KeyError(kind)

    def _said(self, kind: str) -> str:
        if kind == "hysteresis" and self.correction is not None:
            return (f"the readings were corrected to the mean thermal state for T24's thermal hysteresis d = "
                    f"({_fmt(self.correction)}) nT (GUM 3.2.4): the correction's uncertainty")
        return self.checks[kind]["message"] if kind in self.checks else f"{kind} term found"

    def _widened(self, ds, step_var) -> np.ndarray:
        """The terms' covariance per axis with an error of variance step_var (3,) per temperature step."""
        cov = self.cov.copy()
        if step_var is not None:
            groups = np.unique(np.asarray(ds.group, object).astype(str), return_inverse=True)[1]
            for i in range(3):
                per_step = np.stack([np.bincount(groups, row, groups.max() + 1) for row in self.maps[i]])
                cov[i] += step_var[i] * per_step @ per_step.T
        return cov

    def sources(self, ds, cal, wander_var, reference_var, notes: list[str],
                hysteresis_only: bool = False, carried: bool = False) -> list[InputSource]:
        """The terms as one source, their coefficients' covariance widened by what changes from one step
        to the next (the offset's wander, the reference's error), which the white-noise covariance misses:
        the terms share the steps with them; and the hysteresis state, the DUT's own hysteresis in use
        (its estimate's share of the reference's error is the first source's). hysteresis_only: for a
        model other than T24, whose own residual (the misfit) holds what it cannot follow of the other
        terms: the hysteresis alone, as it moved the data. carried: the readings were corrected for the
        hysteresis and the fit's linearisation carries the correction's uncertainty (`data_correction`):
        this line leaves the hysteresis out."""
        if not self.found:
            notes.append(f"model checks: no term beyond T24 found (p >= {P_TERM:g})")
            return []
        per_step = [v for v in (wander_var, reference_var) if v is not None]
        k, coef = self.z.shape[2], self.coef
        cov = self._widened(ds, np.sum(per_step, axis=0) if per_step else None)
        hysteresis = np.concatenate([np.full(p.shape[2], kind == "hysteresis") for kind, p in self.parts])
        sigma = np.zeros((3 * k, 3 * k))
        a = np.zeros((len(ds), 3, 3 * k))
        for i in range(3):
            block = slice(k * i, k * i + k)
            sigma[block, block] = cov[i] + np.outer(coef[i], coef[i])
            if not carried:  # carried: the linearisation moves the estimate with the references already
                a[:, i, block] = np.where(hysteresis, self.z[:, i, :], 0.0)
        if carried:
            sigma[np.tile(hysteresis, 3)] = 0.0
            sigma[:, np.tile(hysteresis, 3)] = 0.0
        parts, mid = self.parts, self.mid

        def grid_effect(grid_h, grid_temp):
            """What a T24 fit over the grid cannot follow of each curvature or cubic term there."""
            h = np.asarray(grid_h, float)
            g_temp = np.full(len(h), mid) if grid_temp is None else np.asarray(grid_temp, float)
            zg = np.concatenate([_terms(kind, h, g_temp, np.zeros(len(h)), mid) for kind, _ in parts], axis=2)
            x = t24_regressors(h, g_temp, cal.temp_ref_c)
            out = np.zeros((len(h), 3, 3 * k))
            for i in range(3):
                left = zg[:, i, :] - x @ np.linalg.lstsq(x, zg[:, i, :], rcond=None)[0]
                out[:, i, k * i:k * i + k] = np.where(hysteresis, 0.0, left)
            return out

        said = "; ".join(self._said(kind) for kind in self.found)
        named = [kind for kind in self.found if not (carried and kind == "hysteresis")]
        if hysteresis_only:
            said = self._said("hysteresis") + "; fitted together with T24 on the same data (u^2 + b^2)"
            out = [] if carried else [InputSource("model checks (hysteresis)", sigma, ref_nt=a, origin=said)]
        else:
            out = [] if not named else [InputSource(
                "model checks (" + ", ".join(named) + ")", sigma, ref_nt=a, field_nt=grid_effect,
                origin=said + "; fitted together with T24 (u^2 + b^2)")]
        if "hysteresis" in self.found:
            at = self.column("hysteresis")
            own = self._widened(ds, wander_var)
            d = coef[:, at] + (0.0 if self.correction is None else self.correction)
            size = np.array([max(own[i][at, at], d[i] ** 2) for i in range(3)])
            said = f"either thermal direction at a point of use: +-d ({_fmt(np.sqrt(size))}) nT"
            out.append(InputSource("thermal hysteresis state", np.diag(size), field_nt=everywhere,
                                   distribution="two-point", origin=said))
        return out


    def data_correction(self, direction, noise) -> DataCorrection | None:
        """The hysteresis correction the readings were given (rig/budget/hysteresis.py), as the
        budget's linearisation takes it along (calib/uncertainty/correction.py): its estimate's map from the
        references (this joint fit's, on the corrected readings: the same map), its variance from the
        readings' noise (the fit's statistics' own, `noise` (3,), else this fit's white residual)."""
        if self.correction is None or "hysteresis" not in self.found or direction is None:
            return None
        at = self.column("hysteresis")
        maps = np.stack([self.maps[i][at] for i in range(3)])
        white = np.array([self.cov[i][at, at] for i in range(3)])
        variance = white if noise is None else np.asarray(noise, float) ** 2 * np.sum(maps**2, axis=1)
        return DataCorrection(np.asarray(direction, float), maps, variance)


def _fmt(values) -> str:
    return ", ".join(f"{v:.1f}" for v in values)
