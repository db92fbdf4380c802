"""What `rig commission` measures of a turntable, and how (rig/commission/procedure.py drives it): the
reference on the table is read at every azimuth (45 deg apart) x elevation (-90..90, 45 apart) within the
table's limits, home first and last, and the table's axes are fitted (calib/commissioning/tablefit.py)."""

from __future__ import annotations

import numpy as np

from calib.commissioning.tablefit import PARAM_NAMES, fit_table_axes
from calib.errors import FitError
from rig.core.errors import DeviceFault
from rig.fieldsources.commissioning import Reading, arrays, drift_nt, rows

AZ_STEP_DEG = 45.0
EL_DEG = (-90.0, -45.0, 0.0, 45.0, 90.0)


def design(source, repeats: int) -> list[tuple[tuple[float, ...], str]]:
    (az_lo, az_hi), (el_lo, el_hi) = source.az_limits_deg, source.el_limits_deg
    azimuths = [a for a in np.arange(0.0, 360.0, AZ_STEP_DEG) if az_lo <= a <= az_hi]
    elevations = [e for e in EL_DEG if el_lo <= e <= el_hi]
    home: tuple[tuple[float, ...], str] = ((0.0, 0.0), "table at home")
    one = [home] + [((float(a), float(e)), f"table at az {a:g} el {e:g} deg")
                    for e in elevations for a in azimuths] + [home]
    return one * repeats


def fit(source, readings: list[Reading]) -> dict:
    """The commissioning file's `table:` section."""
    angles, means, se = arrays(readings)
    try:
        fitted = fit_table_axes(angles, means, se)
    except FitError as exc:
        raise DeviceFault(source.name, "commission the table's axes", str(exc)) from None
    return {
        "params": fitted.as_dict(), "covariance": rows(fitted.covariance),
        "std_errors": {n: float(v) for n, v in zip(PARAM_NAMES, fitted.std_errors, strict=True)},
        "residual_rms_nt": float(np.sqrt(np.mean(fitted.residuals_nt**2))), "drift_nt": drift_nt(readings),
    }


def summary_lines(section) -> list[str]:
    params = ", ".join(f"{k} {v:.4g} +- {section.std_errors[k]:.2g}" for k, v in section.params.items())
    return ["  " + params,
            f"  drift {section.drift_nt:.1f} nT"]
