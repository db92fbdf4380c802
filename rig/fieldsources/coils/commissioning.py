"""What `rig commission` measures of coils, and how (rig/commission/procedure.py drives it).

With the reference at the centre (or anywhere, when the coils' geometry carries its readings to the
centre), the coils are driven through a designed set of currents, repeated `repeats` times:
    0; each coil +I/2, +I, +I/2, 0, -I/2, -I, -I/2, 0 (up and down: hysteresis; two levels: linearity);
    each pair of coils at 0.7 I in the four sign combinations; all three at I/2 in the eight;
and the 3x3 matrix and the ambient are fitted with their covariance (calib/commissioning/coilfit.py) against
the currents the supply reports (its read-back, averaged), as every run's references use them: the read-back's
gain and offset errors then cancel between the commissioning and the run. The zero setting,
visited again and again, shows the drift; each level approached from both sides, the hysteresis.
A coil that does not respond, or a field that is not linear in its current, is a fault named by its axis.
"""

from __future__ import annotations

import itertools

import numpy as np

from calib.commissioning.coilfit import fit_coil_matrix
from calib.errors import FitError
from rig.core.errors import ConfigError, DeviceFault
from rig.fieldsources.coils.commissioned import fit_readback
from rig.fieldsources.coils.gradientfit import element_std_errors, fit_gradient
from rig.fieldsources.coils.loopfit import Place, fit_loops, quantity_names
from rig.fieldsources.commissioning import Reading, arrays, drift_nt, floats, rows

AXES = "xyz"
FIELD_PER_AXIS_NT = 60_000.0  # drive each coil to about this: the fields a campaign uses
CURRENT_SHARE = 0.8  # of max_current_a, at most
MAX_NONLINEARITY = 2e-3  # an air-core coil is linear to far better; more means a fault near the coils
MIN_RESPONSE_SHARE = 0.1  # a coil giving less than this share of its declared field is not connected


def design(source, current_a: float | None, repeats: int) -> list[tuple[tuple[float, ...], str]]:
    level = current_a
    if level is None:
        level = CURRENT_SHARE * source.max_current_a
        if source.coil_constants_nt_per_a is not None:
            columns = np.linalg.norm(source.declared_constants, axis=0)
            level = min(level, FIELD_PER_AXIS_NT / float(np.max(columns)))
    if not 0 < level <= source.max_current_a:
        raise ConfigError(f"rig commission: --current {level:g} A is outside 0 .. field_source.max_current_a "
                          f"{source.max_current_a:g} A")
    one: list[tuple[tuple[float, ...], str]] = [((0.0, 0.0, 0.0), "coils at 0 A")]
    for j in range(3):
        for share in (0.5, 1.0, 0.5, 0.0, -0.5, -1.0, -0.5, 0.0):
            setting = [0.0, 0.0, 0.0]
            setting[j] = share * level
            one.append((tuple(setting), f"coil {AXES[j]} at {share * level:+.3f} A"))
    for j, k in itertools.combinations(range(3), 2):
        for sj, sk in itertools.product((1.0, -1.0), repeat=2):
            setting = [0.0, 0.0, 0.0]
            setting[j], setting[k] = 0.7 * sj * level, 0.7 * sk * level
            one.append((tuple(setting), f"coils {AXES[j]}{AXES[k]} at {_fmt_a(setting)} A"))
    for signs in itertools.product((1.0, -1.0), repeat=3):
        setting = [0.5 * s * level for s in signs]
        one.append((tuple(setting), f"coils xyz at {_fmt_a(setting)} A"))
    return one * repeats


def _fitted(source, readings: list[Reading]):
    """(the coil fit, the currents it was fitted against, which): against the read-backs where every
    setting has one (what flowed as the supply reports it: what the run uses), else the commanded ones."""
    currents, means, se = arrays(readings)
    readbacks = [r.readback for r in readings]
    fitted_to = "commanded"
    if all(r is not None for r in readbacks):
        currents, fitted_to = np.array(readbacks, float), "readback"
    try:
        fitted = fit_coil_matrix(currents, means, se)
    except FitError as exc:
        raise DeviceFault(source.name, f"commission coil {exc.axis or 'xyz'}", str(exc)) from None
    _check_response(source, fitted, currents)
    return fitted, currents, fitted_to


def fit(source, readings: list[Reading], reference_position_mm) -> dict:
    """The commissioning file's `coils:` section."""
    fitted, currents, fitted_to = _fitted(source, readings)
    matrix = fitted.matrix_nt_per_a
    position = np.asarray(reference_position_mm or (0.0, 0.0, 0.0), float)
    if np.any(position != 0):  # measured where the reference sits: carried to the centre
        matrix = _centre_matrix(source.geometry, matrix, position)
    se_matrix, se_ambient = fitted.std_errors()
    readback = fit_readback(readings)
    return {
        "matrix_nt_per_a": rows(matrix), "ambient_nt": floats(fitted.ambient_nt),
        "covariance": rows(_symmetric(fitted.covariance)),
        "std_errors_matrix_nt_per_a": rows(se_matrix), "std_errors_ambient_nt": floats(se_ambient),
        "residual_rms_nt": floats(fitted.residual_rms_nt),
        "nonlinearity_ppm": floats(1e6 * fitted.nonlinearity),
        "hysteresis_nt": _hysteresis_nt(readings), "drift_nt": drift_nt(readings),
        "current_a": float(np.max(np.abs(currents))), "fitted_to": fitted_to,
        **({} if readback is None else {"current_readback": readback}),
    }


def fit_place(source, readings: list[Reading], position_mm, created_utc: str, settings: list[dict]) -> dict:
    """One more place's record (`coils.places[]`): the matrix as measured there, not carried anywhere."""
    fitted, _, _ = _fitted(source, readings)
    return {"position_mm": floats(position_mm), "created_utc": created_utc,
            "matrix_nt_per_a": rows(fitted.matrix_nt_per_a), "ambient_nt": floats(fitted.ambient_nt),
            "covariance": rows(_symmetric(fitted.covariance)),
            "residual_rms_nt": floats(fitted.residual_rms_nt),
            "settings": settings}


def with_loops(source, coils: dict, reference_tolerance_mm: float) -> dict:
    """The `coils:` section with its loops fitted to the centre's matrix and every place's, and the lab
    field's gradient to the ambient at each (rig/fieldsources/coils/gradientfit.py)."""
    centre = np.asarray(coils["matrix_nt_per_a"], float)
    places = [Place(np.asarray(p["position_mm"], float), np.asarray(p["matrix_nt_per_a"], float),
                    np.asarray(p["covariance"], float)[:9, :9]) for p in coils["places"]]
    fitted = fit_loops(centre, np.asarray(coils["covariance"], float)[:9, :9], source.geometry, places,
                       reference_tolerance_mm)
    out = {**coils, "loops": {
        "deviations": fitted.deviations.tolist(), "covariance": rows(_symmetric(fitted.covariance)),
        "reference_offset_mm": floats(fitted.reference_offset_mm), "unidentified": fitted.unidentified,
        "chi2": fitted.chi2, "dof": fitted.dof}}
    return with_gradient(source, out, (0.0, 0.0, 0.0))  # places are added only to a file from the centre


def with_other_references(source, coils: dict, others: list[dict], reference_position_mm) -> dict:
    """The `coils:` section with the other reference magnetometers' ambients (rig/commission/otherrefs.py)
    and the gradient they show."""
    return with_gradient(source, {**coils, "other_references": others}, reference_position_mm)


def with_gradient(source, coils: dict, reference_position_mm) -> dict:
    """The `coils:` section with the lab field's gradient fitted to every ambient it holds: its own (where
    the reference sat), each place's, each other reference's (rig/fieldsources/coils/gradientfit.py)."""
    out = {key: value for key, value in coils.items() if key != "gradient"}
    own = np.asarray(coils["ambient_nt"], float)
    where = reference_position_mm or (0.0, 0.0, 0.0)
    ambients = [(where, own, np.asarray(coils["covariance"], float)[9:, 9:])]
    ambients += [(p["position_mm"], p["ambient_nt"], np.asarray(p["covariance"], float)[9:, 9:])
                 for p in coils.get("places", [])]
    differences = [(np.subtract(o["position_mm"], where), o["difference_nt"], o["covariance"])
                   for o in coils.get("other_references", [])]
    gradient = fit_gradient(ambients, source.ambient_gradient_nt_per_m, differences)
    if gradient is not None:
        out["gradient"] = {
            "nt_per_m": rows(gradient.nt_per_m), "covariance": rows(_symmetric(gradient.covariance)),
            "unidentified": gradient.unidentified, "chi2": gradient.chi2, "dof": gradient.dof,
            "places": gradient.places, "prior_nt_per_m": source.ambient_gradient_nt_per_m}
    return out


def loop_lines(section) -> list[str]:
    """What the places show of each loop: the fitted quantities with their standard errors, and what
    they leave unidentified."""
    loops = section.loops
    if loops is None:
        return gradient_lines(section)
    values = np.asarray(loops.deviations, float).ravel()
    se = np.sqrt(np.diag(np.asarray(loops.covariance, float)))
    names = quantity_names()
    out = [f"  loops fitted to the matrices at the centre and {len(section.places)} place(s) "
           f"(chi2 {loops.chi2:.1f} for {loops.dof} degrees of freedom):"]
    for j in range(3):
        cells = ", ".join(f"{names[i].split(' ', 1)[0]} {names[i].split(' ', 1)[1]} {values[i]:+.3g} +- "
                          f"{se[i]:.2g}" for i in range(10 * j, 10 * j + 10))
        out.append(f"    {cells}")
    if loops.unidentified:
        out.append("  not identified by these places (their tolerance stays in the budget): "
                   + ", ".join(loops.unidentified))
    return out + gradient_lines(section)


def gradient_lines(section) -> list[str]:
    """The lab field's gradient the places' ambients show, with its standard errors."""
    gradient = getattr(section, "gradient", None)
    if gradient is None:
        return []
    g = np.asarray(gradient.nt_per_m, float).ravel()
    se = element_std_errors(gradient.covariance).ravel()
    cells = ", ".join(f"G{'xyz'[k // 3]}{'xyz'[k % 3]} {g[k]:+.0f} +- {se[k]:.0f}"
                      for k in (0, 1, 2, 4, 5, 8))  # the symmetric tensor's upper triangle
    others = [o.name for o in getattr(section, "other_references", [])]
    where = f"{gradient.places} places" + (f", {', '.join(others)} among them" if others else "")
    out = [f"  ambient gradient from the ambient at {where} (nT/m; chi2 {gradient.chi2:.1f} for "
           f"{gradient.dof} degrees of freedom): {cells}"]
    if gradient.unidentified:
        out.append("  not identified by these places (the stated ambient_gradient_nt_per_m stays): "
                   + ", ".join(gradient.unidentified))
    return out


def summary_lines(section) -> list[str]:
    """The fitted matrix with its standard errors, the ambient and the figures of merit."""
    out = []
    for i, (row, se) in enumerate(zip(section.matrix_nt_per_a, section.std_errors_matrix_nt_per_a,
                                      strict=True)):
        cells = "  ".join(f"{v:11.2f} +- {e:6.2f}" for v, e in zip(row, se, strict=True))
        out.append(f"  {AXES[i]}: {cells}  nT/A")
    out.append("  ambient (" + ", ".join(f"{v:.1f}" for v in section.ambient_nt) + ") nT; nonlinearity ("
               + ", ".join(f"{v:.0f}" for v in section.nonlinearity_ppm) + f") ppm; hysteresis "
               f"{section.hysteresis_nt:.1f} nT; drift {section.drift_nt:.1f} nT")
    rb = section.current_readback
    if rb is not None:
        out.append("  current read-back against commanded: gain (" + ", ".join(
            f"{g:+.0f} +- {e:.0f}" for g, e in zip(rb.gain_ppm, rb.std_errors_gain_ppm, strict=True))
            + ") ppm, offset (" + ", ".join(f"{o:+.3f} +- {e:.3f}" for o, e in zip(
                rb.offset_ma, rb.std_errors_offset_ma, strict=True)) + ") mA")
    return out + loop_lines(section)


def _check_response(source, fitted, currents: np.ndarray) -> None:
    """Each coil responds as declared (within a factor) and linearly."""
    declared = source.declared_constants
    for j in range(3):
        column = float(np.linalg.norm(fitted.matrix_nt_per_a[:, j]))
        if declared is not None:
            expected = float(np.linalg.norm(declared[:, j]))
            if column < MIN_RESPONSE_SHARE * expected:
                raise DeviceFault(source.name, f"commission coil {AXES[j]}",
                                  f"the field changes by {column:.4g} nT/A, {column / expected:.1%} of the "
                                  f"declared {expected:.4g} nT/A: the coil does not respond")
        if fitted.nonlinearity[j] > MAX_NONLINEARITY:
            top = float(np.max(np.abs(currents[:, j])))
            raise DeviceFault(source.name, f"commission coil {AXES[j]}",
                              f"the field is not linear in the current: {fitted.nonlinearity[j]:.2%} off at "
                              f"{top:.3g} A (a saturating reference, iron near the coils, or the supply)")


def _centre_matrix(geometry, measured: np.ndarray, position_mm: np.ndarray) -> np.ndarray:
    """The centre matrix whose field at `position_mm` is `measured` (a few fixed-point steps: the map
    from centre to position is the identity to within the field's non-uniformity)."""
    centre = measured.copy()
    for _ in range(20):
        step = measured - geometry.matrices_at(centre, [position_mm])[0]
        centre = centre + step
        if np.max(np.abs(step)) < 1e-9 * np.max(np.abs(measured)):
            break
    return centre


def _hysteresis_nt(readings: list[Reading]) -> float:
    """The largest difference between readings at one current reached from above and from below."""
    worst = 0.0
    for i in range(1, len(readings) - 1):
        here = np.asarray(readings[i].setting)
        for k in range(i + 1, len(readings)):
            if np.array_equal(readings[k].setting, here) and np.any(here != 0):
                before_i = np.abs(readings[i - 1].setting).sum()
                before_k = np.abs(readings[k - 1].setting).sum()
                if before_i != before_k:  # approached from a smaller and from a larger current
                    gap = np.linalg.norm(readings[i].measured.vector_nt - readings[k].measured.vector_nt)
                    worst = max(worst, float(gap))
                break
    return worst


def _symmetric(cov) -> np.ndarray:
    """A covariance written exactly symmetric (the solver's rounding is not; the file's check is exact)."""
    cov = np.asarray(cov, float)
    return 0.5 * (cov + cov.T)


def _fmt_a(setting) -> str:
    return "(" + ", ".join(f"{v:+.3f}" for v in setting) + ")"
