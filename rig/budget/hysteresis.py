"""The DUT's thermal hysteresis, corrected in its readings before any model is fitted (GUM 3.2.4).

An AMR's offset stands +d apart after a heating and -d after a cooling. A plan's history is seldom
balanced (the demo heats through three of its four steps), so every model's offset and its temperature
coefficient absorb the imbalance: a systematic error of known size, which GUM asks to correct rather than
to budget. T24's model checks find the hysteresis (rig/budget/modelerror.py, p < P_TERM) and estimate
d together with the other terms they find; the readings are then taken to the DUT's mean thermal state,
h + d_n S^-1 d (d_n the thermal direction of each sample, S the DUT's scale at the data's middle
temperature), and every model is fitted to them. What the budget keeps is the correction's own
uncertainty and the state a reading is in at a point of use (+-d). A linear fit's budget (T24, T36, P12)
takes the correction along in its linearisation (calib/uncertainty/correction.py): every source that changes
the references moves the estimate too. The scalar fit's Monte Carlo refits do not redo the correction: its
budget keeps the hysteresis line, the estimate fitted again on the corrected readings (about zero) and
its u widened by the errors that change from one step to the next.

    ds, checks = corrected(ds, direction)   # checks: T24's model checks of the readings as taken
    ds.source.get(CORRECTED)                 # where corrected: d per axis (nT), CORRECTED_U its u
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rig.budget.modelerror import CORRECTED, CORRECTED_U, TermsFit, record_model_checks


def corrected(ds, direction) -> tuple[object, list[dict] | None]:
    """(the readings in the mean thermal state where T24's checks find a thermal hysteresis, else as they
    are; T24's model checks of the readings as taken, None where the data cannot be checked: no
    reference, temperatures or thermal direction)."""
    if direction is None or ds.ref_nt is None or ds.temp_c is None or len(ds) == 0:
        return ds, None
    import calib
    from calib.errors import CalibError

    try:
        cal = calib.fit(ds, "t24")
    except CalibError:  # too few samples or temperatures for T24 (another model may still fit): unchecked
        return ds, None
    record_model_checks(cal, ds, direction)
    terms = TermsFit(ds, cal, direction, np.ones(len(ds)))
    if "hysteresis" not in terms.found:
        return ds, cal.stats["model_checks"]
    at = terms.column("hysteresis")
    offset = terms.coef[:, at]
    u = np.sqrt([terms.cov[i][at, at] for i in range(3)])
    s = np.asarray(cal.params["S"], float) + terms.mid * np.asarray(cal.params["K"], float)
    shift = np.linalg.solve(s, offset)
    moving = np.asarray(direction, float)[:, None]
    source = {**ds.source, CORRECTED: offset.tolist(), CORRECTED_U: u.tolist()}
    return dataclasses.replace(ds, h_nt=ds.h_nt + moving * shift, source=source), cal.stats["model_checks"]
