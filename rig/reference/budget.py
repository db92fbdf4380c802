"""The uncertainty budget of a session's calibrations: what each input the reference field and the
temperature rest on could have been, as Monte Carlo sources for calib/uncertainty.py.

    run = RunInputs.of_session(reader)               # once per session (read-only)
    ds, ambient = run.refined(ds)                    # references with the run's best ambient
    cal.uncertainty = run.budget(dut, ds, cal).as_dict()

The inputs and how they are drawn (standard uncertainties u; a +-tolerance is a rectangular distribution):
- fit (statistical): the DUT's own noise, redrawn with the fit's residual scatter;
- coil matrix: the commissioning's covariance (or, declared, `constants_uncertainty_ppm` of each element's
  column); the field at each sample changes by dM(r) I, I the sample's currents;
- reference magnetometer: its calibration's stated uncertainty (`uncertainty.expanded / k`, else its
  standard errors): the fields it measured (the commissioned matrix, the ambient, the site field) are off
  by its calibration's error, B_true = T B_measured + d;
- ambient: the uncertainty of the run's best estimate from all its measurements (start, each temperature
  step, end; rig/reference/ambient.py), with which the fits make every reference (`RunInputs.refined`); the
  site field of a turntable: its measurement's standard error;
- position: each DUT anywhere within +-position_tolerance_mm of its position_mm (coils with a geometry);
- coil geometry: every loop's size and spacing within +-geometry.tolerance_mm;
- table axes: the commissioning's covariance of the table's seven parameters (turntable);
- temperature: the temperature source's accuracy (+-temp_accuracy_c, else its datasheet's), the
  DUT-to-probe gradient (+-temp_gradient_c_per_c per degC away from 25 degC) and, on a ramp, the thermal
  lag the fit corrected for (its standard error times how fast the temperature moved).
The grid the calibrated field is judged on: the plan's field targets at the plan's temperatures.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import zlib
from dataclasses import dataclass

import numpy as np

from calib import models
from calib.calibration import Calibration
from calib.uncertainty import Budget, Draw, Source, monte_carlo, residual_sigma_nt, statistical
from rig.reference import chain_record
from rig.reference.ambient import AmbientModel
from rig.session.events import Reason

UNSTATED_TEMP_ACCURACY_C = 1.0  # a temperature source whose datasheet states no accuracy
GRADIENT_REFERENCE_C = 25.0  # the DUT and its probe agree at room temperature
RATE_WINDOW_S = 60.0


def refit_like(cal: Calibration):
    """A function fitting a dataset exactly as `cal` was (model, temperature reference, rows used, the
    scalar fit's choices), without the robust iterations: the rows they flagged stay out."""
    spec = models.spec(cal.model)
    options = models.FitOptions(
        temp_ref_c=cal.temp_ref_c,
        field_norm_nt=cal.stats.get("field_norm_nt"),
        temperature_terms="KA_per_c" in cal.params if cal.model == "scalar" else None,
        balance_orientations=bool(cal.stats.get("balance_orientations", False)),
    )
    weights = fit_weights(cal)
    return lambda ds: spec.fit_weighted(ds, weights, options)[0]


def fit_weights(cal: Calibration) -> np.ndarray | None:
    """The row weights `cal` was fitted with: the robust iterations' outliers left out."""
    return None if cal.outliers is None or not cal.outliers.any() else (~cal.outliers).astype(float)


@dataclass
class RunInputs:
    """What a session says about its reference chain, read once for all its DUTs."""

    station: object
    plan: object
    point_refs: dict[str, dict]
    site: list[dict]  # the ambient / site field measurements, in time order: {t, vector_nt, std_error_nt}
    reference_cal: Calibration | None  # the reference magnetometer that measured the field source
    reference_temp_accuracy_c: float = 0.0  # of its temperature source, when its calibration needs one
    points: dict[str, dict] = dataclasses.field(default_factory=dict)  # the done points: {id: {target, ...}}

    @classmethod
    def of_session(cls, reader) -> RunInputs:
        chain = reader.snapshot(chain_record.SNAPSHOT) or {}
        plan, station = chain_record.recorded_plan_and_station(reader.path, reader.info(), chain)
        site = [{"t": e.t, **e.data} for e in reader.events()
                if e.code in (Reason.SITE_FIELD_MEASURED, Reason.SITE_FIELD_CHECKED, Reason.SITE_FIELD_DRIFT)
                and "vector_nt" in e.data]
        cals = chain.get("reference_calibrations") or {}
        source = station.field_source
        name = source.measuring_magnetometer([r.name for r in station.reference_magnetometers])
        com = source.commissioned
        if com is not None:
            name = com.record.reference_magnetometer.name
        reference_cal = Calibration.from_dict(cals[name]) if name in cals else None
        refs = {r.name: r for r in station.reference_magnetometers}
        accuracy = 0.0
        if name in refs and refs[name].temp_source is not None:
            accuracy, _ = temperature_accuracy_c(station, refs[name])
        points = {p["id"]: {"target": json.loads(p["target_json"]), "setpoint_c": p["setpoint_c"]}
                  for p in reader.points() if p["state"] == "done"}
        return cls(station, plan, reader.point_references(), site, reference_cal, accuracy, points)

    # --- the budget of one DUT's calibration ----------------------------------------------------------
    def budget(self, dut: str, ds, cal: Calibration, *, rng: np.random.Generator | None = None,
               draws: int | None = None) -> Budget:
        rng = rng or np.random.default_rng(zlib.crc32(f"{dut}/{cal.model}".encode()))
        sources, notes = self.sources(dut, ds, cal)
        kwargs = {} if draws is None else {"draws": draws, "draws_per_source": max(20, draws // 3)}
        budget = monte_carlo(ds, cal, sources, refit_like(cal), self._grid, rng=rng,
                             reference_map=reference_map_of(ds, cal), **kwargs)
        budget.notes = notes
        return budget

    @functools.cached_property
    def _grid(self) -> tuple[np.ndarray, np.ndarray]:
        """The run's field targets (as fields at the centre) at the run's temperatures: those of the points
        it took (a schedule decided during the run knows its points only then)."""
        source = self.station.field_source
        commands = [_command(p["target"]) for p in self.points.values()]
        fields = np.unique(np.array([source.nominal_field_nt(c) for c in commands]), axis=0)
        temps = np.unique(np.round([p["setpoint_c"] for p in self.points.values()], 1))
        if len(temps) > 8:  # a ramp: its ends and evenly between
            temps = np.linspace(temps.min(), temps.max(), 5)
        grid_f = np.repeat(fields, len(temps), axis=0)
        grid_t = np.tile(temps, len(fields))
        return grid_f, grid_t

    def sources(self, dut: str, ds, cal: Calibration) -> tuple[list[Source], list[str]]:
        notes: list[str] = []
        out = [statistical(ds, residual_sigma_nt(ds, cal))]
        chain = self.station.field_source.budget_chain(self, dut, ds)
        out += [dataclasses.replace(s, reference_only=True) for s in chain.sources(notes)]  # fields only
        out.append(self._temperature(dut, ds, cal, notes))
        return out, notes

    def _temperature(self, dut: str, ds, cal: Calibration, notes: list[str]) -> Source:
        """The probe's accuracy, the DUT-to-probe gradient and, on a ramp, the uncertainty of the thermal
        lag the fit corrected for (its standard error times how fast each sample's temperature moved)."""
        config = self.station.dut(dut)
        accuracy, stated = temperature_accuracy_c(self.station, config)
        if not stated:
            notes.append(f"{dut}: its temperature source's datasheet states no accuracy: "
                         f"+-{accuracy:g} degC assumed (state temp_accuracy_c)")
        gradient = config.temp_gradient_c_per_c
        away = ds.temp_c - GRADIENT_REFERENCE_C
        lag = cal.stats.get("thermal_lag") or {}
        lag_se = lag.get("tau_se_s") if lag.get("applied") else None
        rate = temperature_rate_c_per_s(ds) if lag_se else np.zeros(len(ds))

        def draw(rng: np.random.Generator) -> Draw:
            change = rng.uniform(-accuracy, accuracy) + rng.uniform(-gradient, gradient) * away
            if lag_se:
                change = change - rng.normal(0.0, lag_se) * rate
            return Draw(temp_c=change)

        note = f"+-{accuracy:g} degC, gradient +-{gradient:g} degC/degC"
        return Source("temperature", draw, note + (f", thermal lag +-{lag_se:.3g} s" if lag_se else ""))

    def reference_transform(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(T, d): a draw of how far the reference magnetometer's calibration could be off, as a map from
        what it reported to the field: B = T B_reported + d (at its mean measuring temperature, which its
        temperature source knows to within its accuracy)."""
        cal = self.reference_cal
        temp = np.mean([m["temp_c"] for m in self.site if m.get("temp_c") is not None] or [25.0])
        u = standard_uncertainties(cal)
        drawn = Calibration(cal.model, {k: v + rng.normal(0.0, 1.0, np.shape(v)) * u[k]
                                        for k, v in cal.params.items()}, {}, cal.temp_ref_c)
        off_c = rng.uniform(-self.reference_temp_accuracy_c, self.reference_temp_accuracy_c)
        a, c = _affine(cal, temp)
        a2, c2 = _affine(drawn, temp + off_c)
        t = a2 @ np.linalg.inv(a)
        return t, c2 - t @ c

    @functools.cached_property
    def ambient(self) -> AmbientModel | None:
        """The ambient over the run from all its measurements (coils whose ambient is measured)."""
        if not self.station.field_source.measures_ambient() or not self.site:
            return None
        return AmbientModel.fit(self.site)

    def recorded_ambient(self, ds) -> np.ndarray | None:
        """(N,3): the ambient each sample's reference was made with (None: not recorded)."""
        refs = [self.point_refs.get(p, {}).get("ambient_nt") for p in ds.columns["point"]]
        if any(r is None for r in refs):
            return None
        return np.array(refs, float)

    def refined(self, ds):
        """(ds, what was done): each reference made with the run's best ambient estimate
        (rig/reference/ambient.py)
        instead of the value in use when its point was taken; unchanged where that cannot be done."""
        used = self.recorded_ambient(ds)
        if self.ambient is None or used is None:
            return ds, None
        best = self.ambient.at(ds.columns["t"])
        return dataclasses.replace(ds, ref_nt=ds.ref_nt + best - used), self.ambient.as_dict()


def temperature_rate_c_per_s(ds, window_s: float = RATE_WINDOW_S) -> np.ndarray:
    """How fast each sample's temperature was moving: the change over `window_s` around it (readings a
    fraction of a second apart would give the probe's resolution, not the ramp)."""
    t = ds.columns.get("t")
    if t is None or len(ds) < 2:
        return np.zeros(len(ds))
    order = np.argsort(t, kind="stable")
    ts, temps = t[order], ds.temp_c[order]
    half = window_s / 2
    span = np.minimum(t + half, ts[-1]) - np.maximum(t - half, ts[0])
    change = np.interp(t + half, ts, temps) - np.interp(t - half, ts, temps)
    return np.where(span > 0, change / np.where(span > 0, span, 1.0), 0.0)


def temperature_accuracy_c(station, config) -> tuple[float, bool]:
    """(+- accuracy of a DUT's or reference's temperature source, whether anyone stated it): its own
    `temp_accuracy_c`, else its source's datasheet value, else UNSTATED_TEMP_ACCURACY_C."""
    if config.temp_accuracy_c is not None:
        return config.temp_accuracy_c, True
    sensor = config if config.temp_source == "self" else next(
        s for s in station.temperature_sensors if s.name == config.temp_source)
    accuracy = sensor.spec.temperature_accuracy_c
    return (UNSTATED_TEMP_ACCURACY_C, False) if accuracy is None else (accuracy, True)


def reference_map_of(ds, cal: Calibration):
    """The model's parameters as a linear map of the references, where it is one (T24), else None."""
    if cal.model != "t24":
        return None
    from calib.t24 import reference_map

    return reference_map(ds, fit_weights(cal), cal.temp_ref_c)


def _command(target: dict) -> tuple[float, ...]:
    """A point's stored target as the field source's command: a field vector, or (az, el)."""
    if "field_nt" in target:
        return tuple(target["field_nt"])
    return (target["az_deg"], target["el_deg"])


def standard_uncertainties(cal: Calibration) -> dict[str, np.ndarray]:
    """A calibration's standard uncertainties: its budget's expanded / k, else its standard errors."""
    u = cal.uncertainty
    if u is not None:
        k = float(u["coverage_factor"])
        return {name: np.asarray(u["expanded"][name], float) / k for name in cal.params}
    return {name: np.asarray(cal.std_errors.get(name, np.zeros(np.shape(v))), float)
            for name, v in cal.params.items()}


def _affine(cal: Calibration, temp_c: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, c) with cal.apply(h) = A h + c at `temp_c` (every model is affine in h)."""
    h = np.vstack([np.zeros(3), np.eye(3)])
    out = cal.apply(h, np.full(4, temp_c))
    return (out[1:] - out[0]).T, out[0]
