"""The uncertainty budget of a session's calibrations: every input the reference field and the temperature
rest on, as input quantities for calib.uncertainty.budgeting.budget (the law of propagation where it is exact
or checked to hold, the adaptive Monte Carlo of GUM S1 where it is needed).

    run = RunInputs.of_session(reader)               # once per session (read-only)
    ds, ambient = run.refined(ds)                    # references with the run's best ambient
    cal.uncertainty = run.uncertainty(dut, ds, cal)  # the calibration file's `uncertainty:` section

The inputs (standard uncertainties; a +-tolerance is rectangular), each a line of the budget with its
origin:
- fit (statistical): the DUT's own noise (calib: sigma^2 G^-1);
- the reference field's sources, which each field-source kind supplies (rig/fieldsources/<kind>/budget.py:
  coil matrix, ambient, gradient, position, geometry, loops, current source, the commissioning's
  non-linearity, hysteresis and drift, the coils' drift since; or a table's axes, its site field over the
  run and the gradient its DUTs turn through), and
  the reference magnetometer that measured them (`reference_sources`: its calibration's covariance, else
  its expanded uncertainty / k; a reference calibration that states no uncertainty is refused, never
  taken as zero);
- temperature: the temperature source's accuracy (+-temp_accuracy_c, else its datasheet's) and the
  DUT-to-probe gradient (+-temp_gradient_c_per_c per degC away from 25 degC), rectangular; thermal lag:
  on a ramp, the uncertainty of the lag the fit corrected for times how fast the temperature moved;
- model: the model checks' terms and the misfit beyond the DUT's noise (rig/budget/modelerror.py).
The grid the calibrated field is judged on: the run's field targets at its temperatures.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools
import json
import zlib
from dataclasses import dataclass

import numpy as np

from calib.calibration import Calibration, standard_uncertainty
from calib.uncertainty.budgeting import budget as calib_budget
from calib.uncertainty.fielderror import expanded_norm_at, parameter_covariance
from calib.uncertainty.montecarlo import Budget
from calib.uncertainty.propagation import InputSource, affine_map, reference_source, temperature_source
from rig.budget import modelerror
from rig.core.errors import DataError
from rig.reference import chain_record
from rig.reference.ambient import AmbientModel
from rig.session.events import Reason

UNSTATED_TEMP_ACCURACY_C = 1.0  # a temperature source whose datasheet states no accuracy
GRADIENT_REFERENCE_C = 25.0  # the DUT and its probe agree at room temperature
RATE_WINDOW_S = 60.0


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
    reference_name: str | None = None
    temperature_log: list[dict] = dataclasses.field(default_factory=list)  # the run's temperature rows
    run_utc: dt.datetime | None = None  # when the run started (wall clock)
    _chains: dict = dataclasses.field(default_factory=dict, repr=False)  # dut: (ds, sources, notes)

    @classmethod
    def of_session(cls, reader) -> RunInputs:
        chain = reader.snapshot(chain_record.SNAPSHOT) or {}
        info = reader.info()
        plan, station = chain_record.recorded_plan_and_station(reader.path, info, chain)
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
        started = info.get("wall_started")
        when = None if started is None else dt.datetime.fromtimestamp(started, dt.UTC)
        return cls(station, plan, reader.point_references(), site, reference_cal, accuracy, points, name,
                   reader.temperatures(), when)

    # --- the budget of one DUT's calibration ----------------------------------------------------------
    def budget(self, dut: str, ds, cal: Calibration, *, rng: np.random.Generator | None = None,
               monte_carlo: str = "auto") -> Budget:
        rng = rng or np.random.default_rng(zlib.crc32(f"{dut}/{cal.model}".encode()))
        sources, notes, noise, correction = self.sources(dut, ds, cal)
        b = calib_budget(ds, cal, sources, self._grid, rng=rng, weights=fit_weights(cal),
                         monte_carlo=monte_carlo, noise_nt=noise, correction=correction)
        b.notes = b.notes + notes
        return b

    def uncertainty(self, dut: str, ds, cal: Calibration, **kw) -> dict:
        """The calibration file's `uncertainty:` section (`uncertainty_section`)."""
        return uncertainty_section(self.budget(dut, ds, cal, **kw), cal)

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
        return np.repeat(fields, len(temps), axis=0), np.tile(temps, len(fields))

    def sources(self, dut: str, ds, cal: Calibration) -> tuple:
        """(every input source but the fit's own noise, notes, the readings' noise for the fit's
        statistics where the model sources take a share of its residual, the readings' hysteresis
        correction as the budget takes it along: modelerror.model_sources)."""
        notes: list[str] = []
        out = self._reference_field_sources(dut, ds, notes)
        out += self._temperature(dut, ds, cal, notes)
        per_step = None if self.ambient is None else self.ambient.excess_nt**2
        model, said, noise, correction = modelerror.model_sources(ds, cal, self.thermal_direction(dut, ds),
                                                                  fit_weights(cal), per_step)
        return out + model, notes + said, noise, correction

    def _reference_field_sources(self, dut: str, ds, notes: list[str]) -> list:
        """The field source's sources for one DUT's data, made once for every model fitted to the same
        dataset (their sensitivities are most of a budget's time)."""
        cached = self._chains.get(dut)
        if cached is None or cached[0] is not ds:
            said: list[str] = []
            sources = list(self.station.field_source.budget_chain(self, dut, ds).sources(said))
            cached = self._chains[dut] = (ds, sources, said)
        notes += cached[2]
        return list(cached[1])

    def _temperature(self, dut: str, ds, cal: Calibration, notes: list[str]) -> list:
        """The probe's accuracy and the DUT-to-probe gradient (rectangular) and, on a ramp, the uncertainty
        of the thermal lag the fit corrected for (its standard error times how fast the temperature moved)."""
        config = self.station.dut(dut)
        accuracy, stated = temperature_accuracy_c(self.station, config)
        if not stated:
            notes.append(f"{dut}: its temperature source's datasheet states no accuracy: "
                         f"+-{accuracy:g} degC assumed (state temp_accuracy_c)")
        gradient = config.temp_gradient_c_per_c
        columns = np.column_stack([np.ones(len(ds)), ds.temp_c - GRADIENT_REFERENCE_C])
        out = [temperature_source("temperature", columns, np.diag([accuracy**2, gradient**2]) / 3.0,
                                  distribution="rectangular",
                                  origin=f"+-{accuracy:g} degC, gradient +-{gradient:g} degC/degC")]
        lag = cal.stats.get("thermal_lag") or {}
        lag_se = lag.get("tau_se_s") if lag.get("applied") else None
        if lag_se:
            out.append(temperature_source("thermal lag", -temperature_rate_c_per_s(ds)[:, None],
                                          np.array([[lag_se**2]]), origin=f"+-{lag_se:.3g} s (1 sd)"))
        return out

    # --- the reference magnetometer ---------------------------------------------------------------------
    def reference_sources(self, measured_nt: np.ndarray, notes: list[str]) -> list:
        """Its calibration's error in what it measured (B' (N,3): the fields it reported that went into
        each sample's reference), and its temperature source's accuracy where its calibration has
        temperature terms. DataError when its calibration states no uncertainty."""
        cal = self.reference_cal
        if cal is None:
            notes.append("reference magnetometer: its calibration is not in the session, not in the budget")
            return []
        if cal.uncertainty is None:
            raise DataError(f"reference magnetometer {self.reference_name}: its calibration states no "
                            "uncertainty (no `uncertainty:` section): a reference without one is refused")
        temp = self.reference_temp_c()
        covariance, _ = parameter_covariance(cal)
        out = [reference_source("reference magnetometer", measured_nt, cal, covariance, temp,
                                shared="reference magnetometer",
                                origin=f"{self.reference_name}: its calibration's covariance")]
        if self.reference_temp_accuracy_c > 0 and temp is not None and cal.temp_ref_c is not None:
            a0, c0 = affine_map(cal, temp)
            a1, c1 = affine_map(cal, temp + 1.0)
            d_t = a1 @ np.linalg.inv(a0) - np.eye(3)
            per_c = np.asarray(measured_nt, float) @ d_t.T + (c1 - c0 - d_t @ c0)  # (N,3) per degC
            half = self.reference_temp_accuracy_c
            out.append(InputSource("reference temperature", np.array([[half**2 / 3]]),
                                   ref_nt=per_c[:, :, None], distribution="rectangular",
                                   shared="reference temperature",
                                   origin=f"{self.reference_name}'s temperature source +-{half:g} degC"))
        return out

    def reference_temp_c(self) -> float | None:
        """The reference's mean measuring temperature (its calibration's reference when none was read)."""
        temps = [m["temp_c"] for m in self.site if m.get("temp_c") is not None]
        return float(np.mean(temps)) if temps else self.reference_cal.temp_ref_c

    def reference_position_mm(self) -> np.ndarray:
        refs = {r.name: r for r in self.station.reference_magnetometers}
        ref = refs.get(self.reference_name)
        return np.zeros(3) if ref is None or ref.position_mm is None else np.asarray(ref.position_mm, float)

    def age_days(self, commissioning) -> float:
        """Days from the commissioning to the run (0 when the session does not say when it ran)."""
        if self.run_utc is None:
            return 0.0
        return (self.run_utc - commissioning.created).total_seconds() / 86_400.0

    # --- the ambient, the thermal history ---------------------------------------------------------------
    def thermal_direction(self, dut: str, ds) -> np.ndarray:
        """+1 heating, -1 cooling, 0 unknown for every sample, from the run's temperature log and the
        samples themselves (rig/budget/modelerror.py)."""
        history = [(r["t"], r["duts"][dut]) for r in self.temperature_log
                   if r["duts"].get(dut) is not None]
        return modelerror.thermal_direction(ds.columns["t"], ds.temp_c, history)

    @functools.cached_property
    def ambient(self) -> AmbientModel | None:
        """The ambient over the run from all its measurements (coils whose ambient is measured, a table's
        site field)."""
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
        (rig/reference/ambient.py) instead of the value in use when its point was taken; unchanged where
        that cannot be done."""
        found = None if self.ambient is None else self.station.field_source.ambient_in_references(self, ds)
        if found is None:
            return ds, None
        used, by = found
        change = self.ambient.at(ds.columns["t"]) - used
        if by is not None:
            change = np.einsum("nij,nj->ni", by, change)
        return dataclasses.replace(ds, ref_nt=ds.ref_nt + change), self.ambient.as_dict()


def uncertainty_section(b: Budget, cal: Calibration) -> dict:
    """The calibration file's `uncertainty:` section: the budget (its parameters' full covariance
    included), and the model error a user adds at any field and temperature to what that covariance
    gives (rig apply --uncertainty, calib/uncertainty/fielderror.py): the normal part, and the DUT's thermal
    state at a point of use (+-d per axis, two-point) apart, so that the radius there follows its
    distribution. Beside the largest radius of the vector error, the largest 95 % interval of |B|'s error over
    the same grid, as rig apply computes it (`expanded_norm_error_nt`): what a scalar fit answers for."""
    out = b.as_dict()
    out["model_error_nt"] = model_error_nt(b).tolist()
    state = model_error_nt(b, two_point=True)
    if np.any(state > 0):
        out["hysteresis_state_nt"] = state.tolist()
    if b.linear is not None:  # at the grid's raw readings, which the budget holds
        stated = dataclasses.replace(cal, uncertainty=out)
        size_u = expanded_norm_at(stated, b.linear.grid_h_nt, b.linear.grid_temp_c)
        out["expanded_norm_error_nt"] = float(np.max(size_u))
    return out


def model_error_nt(b: Budget, two_point: bool = False) -> np.ndarray:
    """(3,): the standard uncertainty per axis of the field error no parameter carries (the model
    sources' direct effects), RMS over the grid: of the normal (and rectangular) sources, or with
    `two_point` of the two-point ones (the thermal state: +- this)."""
    total = np.zeros(3)
    for c in b.linear.contributions:
        if c.grid_effect is not None and (c.source.distribution == "two-point") == two_point:
            sigma = np.atleast_2d(c.source.covariance)
            total += np.mean(np.einsum("giq,qr,gir->gi", c.grid_effect, sigma, c.grid_effect), axis=0)
    return np.sqrt(total)


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


def _command(target: dict) -> tuple[float, ...]:
    """A point's stored target as the field source's command: a field vector, or (az, el)."""
    if "field_nt" in target:
        return tuple(target["field_nt"])
    return (target["az_deg"], target["el_deg"])


def standard_uncertainties(cal: Calibration) -> dict[str, np.ndarray]:
    """A calibration's standard uncertainties: its budget's expanded / k (DataError without one)."""
    if cal.uncertainty is None:
        raise DataError("the calibration states no uncertainty")
    return {name: standard_uncertainty(cal.uncertainty, name) for name in cal.params}
