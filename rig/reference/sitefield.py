"""The measured ambient / site field: what a reference magnetometer at the DUT position reads with the
field source's own field off (coils at 0 A) or at its home pose (table at home: NED).

    cals = load_reference_calibrations(station, station_path, station_text)  # located errors
    monitor = SiteFieldMonitor(rig, cals, settle_s=plan.settle_s)
    first = monitor.measure_at_start(session.log_event, plan.name, points)   # recorded; limits re-checked
    reference = reference_for(station, first.vector_nt)                     # used for every point
    monitor.recheck(engine.event, step_c)                                    # each step; Hold on drift
    reference = reference_for(station, monitor.in_use.vector_nt)            # that step's points
    monitor.check_at_end(session.log_event)                                  # after the last point

A reference magnetometer is a station device (`reference_magnetometers`), never a DUT: it is not fitted and
not in the outputs. Its calibration file is applied to every reading, with its temperature source's
temperature when the calibration has temperature terms. The start value is used for every reference
vector until a later measurement differs from it by more than its noise (SIGNIFICANT standard errors):
the later one is then used from that temperature step on. At each temperature step the field is measured
again, the change recorded, and the run held (Reason.SITE_FIELD_DRIFT) when it moved more than the field
source's drift limit; once more after the last point, so that the drift over the whole run is on record
(the uncertainty budget reads these measurements, rig/budget/run_inputs.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.calibration import Calibration
from calib.io import calfile
from calib.models import registry
from rig.config.lab import reference_certificate
from rig.core.errors import ERRORS, ConfigError, DataError, DeviceFault
from rig.core.yamlload import locate_in_text
from rig.engine.commands import FAILED, Hold
from rig.session.events import Kind, Reason, code_of, device_of

MIN_GOOD_SAMPLES = 2  # a standard error needs two readings
READBACK_READS = 30  # read-backs averaged at a setting: their own noise, not the source's, is then small
SIGNIFICANT = 3.0  # a re-measured field replaces the one in use when they differ by this many standard errors


@dataclass(frozen=True)
class FieldMeasurement:
    """The mean calibrated reading of the reference magnetometer and its standard error, nT."""

    vector_nt: np.ndarray
    std_error_nt: np.ndarray
    n: int
    temp_c: float | None
    source_field_nt: np.ndarray | None = None  # the field source's own field, taken out of vector_nt

    def as_data(self) -> dict:
        out = {"vector_nt": [round(float(v), 3) for v in self.vector_nt],
               "std_error_nt": [round(float(v), 3) for v in self.std_error_nt], "n": self.n,
               "temp_c": None if self.temp_c is None else round(self.temp_c, 3)}
        if self.source_field_nt is not None:
            out["source_field_nt"] = [round(float(v), 3) for v in self.source_field_nt]
        return out

    def without(self, field_nt, se_nt) -> FieldMeasurement:
        """This measurement with a known field (and its standard error) taken out."""
        se = np.sqrt(np.square(self.std_error_nt) + np.square(se_nt))
        field = np.asarray(field_nt, float)
        return FieldMeasurement(self.vector_nt - field, se, self.n, self.temp_c, field)


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:.1f}" for x in v) + ")"


def calibration_path(station_path: str | Path, calibration: str) -> Path:
    """A reference's calibration file: as written when absolute, else relative to the station file."""
    path = Path(calibration)
    return path if path.is_absolute() else Path(station_path).parent / path


def load_reference_calibrations(station, station_path: str | Path, station_text: str
                                ) -> dict[str, Calibration]:
    """{reference name: its calibration}; a missing, unreadable or unusable file is a ConfigError that
    names the station file, the key and its line."""
    out = {}
    for i, ref in enumerate(station.reference_magnetometers):
        def refuse(key: str, what: str, i: int = i) -> ConfigError:
            return ConfigError(locate_in_text(str(station_path), station_text,
                                              ("reference_magnetometers", i, key), what))

        path = calibration_path(station_path, ref.calibration)
        try:
            cal = calfile.load(path)
        except DataError as exc:
            raise refuse("calibration", str(exc)) from None
        if cal.uncertainty is None:
            raise refuse("calibration", f"{path}: states no uncertainty (no `uncertainty:` section): a "
                         "reference magnetometer's calibration must state its expanded uncertainty")
        if not registry.spec(cal.model).vector:
            raise refuse("calibration", f"{path}: a {cal.model} calibration gives the field only up to a "
                         f"rotation; a reference needs a vector model ({', '.join(registry.VECTOR_MODELS)})")
        made_for = cal.source.get("device_type")
        if made_for is not None and made_for != ref.type:
            raise refuse("calibration", f"{path}: made for a {made_for}, not this {ref.type}")
        if registry.needs_temperature(cal.model, cal.params) and ref.temp_source is None:
            raise refuse("temp_source", f"its {cal.model} calibration has temperature terms: name a "
                         "temperature sensor beside it, or 'self'")
        reference_certificate(path)  # a certificate it transcribes is whole, or refused naming its key
        out[ref.name] = cal
    return out


class ReferenceReader:
    """A reference magnetometer as a measuring instrument: the mean of `samples` calibrated readings
    (its calibration applied with its temperature source's temperature when it has temperature terms)."""

    def __init__(self, rig, config, calibration: Calibration):
        self.rig = rig
        self.config = config
        self.device = rig.built.devices[config.name]
        self.calibration = calibration
        source = config.temp_source
        self.temp_device = (None if source is None else self.device if source == "self"
                            else rig.temp_sensors[source])

    @property
    def name(self) -> str:
        return self.config.name

    def read_mean(self, what: str, *, flagged_is_fault: bool = False) -> FieldMeasurement:
        """Read now. A flagged reading (overflow, saturation) is left out, or with `flagged_is_fault` is a
        DeviceFault naming `what` was being measured; fewer than two usable readings is one too."""
        raw, temps = [], []
        for _ in range(self.config.samples):
            sample = self.device.read()
            if sample.flags:  # overflow, saturation: not a reading of the field
                if flagged_is_fault:
                    raise DeviceFault(self.name, what, f"reading {', '.join(sorted(sample.flags))}: the "
                                      "field is beyond its range")
                continue
            temp = None
            if self.temp_device is self.device:
                temp = sample.temp_c
            elif self.temp_device is not None:
                temp = self.temp_device.read().temp_c
            raw.append(sample.field_nt)
            temps.append(np.nan if temp is None else temp)
        if len(raw) < MIN_GOOD_SAMPLES:
            raise DeviceFault(self.name, what,
                              f"only {len(raw)} of {self.config.samples} readings were usable")
        temp_c = np.array(temps, float)
        needs_temp = registry.needs_temperature(self.calibration.model, self.calibration.params)
        if needs_temp and np.isnan(temp_c).any():
            raise DeviceFault(self.name, what, "its temperature source gave no temperature")
        field = self.calibration.apply(np.array(raw, float), temp_c if needs_temp else None)
        se = field.std(axis=0, ddof=1) / np.sqrt(len(field))
        mean_temp = None if np.isnan(temp_c).all() else float(np.nanmean(temp_c))
        return FieldMeasurement(field.mean(axis=0), se, len(field), mean_temp)


def readback_mean(rig, source, reads: int = READBACK_READS
                  ) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """(mean, standard error) of what the field source reports of its setting over `reads` reads (coil
    read-back currents); None when it reports nothing beyond the setting."""
    values = [source.setting_readback(rig.field_source.read()) for _ in range(reads)]
    if any(v is None for v in values):
        return None
    values = np.array(values, float)
    se = values.std(axis=0, ddof=1) / np.sqrt(len(values)) if len(values) > 1 else np.zeros(values.shape[1])
    return tuple(float(v) for v in values.mean(axis=0)), tuple(float(v) for v in se)


COMMISSION_SETTLE_S = 0.5  # `rig commission`: a setting read this long after the source says it settled


def settle_at(rig, source, setting, settle_s: float) -> None:
    """Drive the field source to `setting` (currents or table angles) and let it settle."""
    mover = rig.field_source
    mover.set(setting)
    mover.wait_settled(source.settle_timeout_s())
    if settle_s > 0:
        rig.clock.sleep(settle_s)


class SiteFieldMonitor:
    """Measures the field source's ambient / site field with its reference magnetometer."""

    def __init__(self, rig, calibrations: dict[str, Calibration], *, settle_s: float = 0.0):
        station = rig.station
        self.rig = rig
        self.source = station.field_source
        refs = {r.name: r for r in station.reference_magnetometers}
        name = self.source.measuring_magnetometer(list(refs))
        if name not in refs:  # the station model refuses this already; a guard for hand-built stations
            raise ConfigError(f"station {station.name}: the {self.source.measured_name} must be measured, "
                              "but no reference magnetometer is named for it")
        self.reader = ReferenceReader(rig, refs[name], calibrations[name])
        self.settle_s = settle_s
        self.start: FieldMeasurement | None = None
        self.in_use: FieldMeasurement | None = None  # the value the references are made with

    @property
    def name(self) -> str:
        return self.reader.name

    def measure(self) -> FieldMeasurement:
        """Field source to its measurement setting, settled; then the mean of `samples` calibrated
        readings, less the field the source still makes there as its read-back says (a coil supply's
        offset flows at 0 A): the run's references add the field of the read-back currents to it."""
        settle_at(self.rig, self.source, self.source.measurement_setting(), self.settle_s)
        m = self.reader.read_mean("measure the " + self.source.measured_name)
        readback = readback_mean(self.rig, self.source)
        where = self.reader.config.position_mm
        own = None if readback is None else self.source.own_field_nt(*readback, where)
        return m if own is None else m.without(*own)

    def measure_at_start(self, log_event: Callable, plan_name: str, points) -> FieldMeasurement:
        """The value every reference of the run uses: measured, recorded, and the plan's limits checked
        with it (LimitError before the first field is set)."""
        m = self.measure()
        self.start = self.in_use = m
        what = self.source.measured_name
        log_event(Kind.SITE_FIELD, f"{what} measured by {self.name}: {_fmt(m.vector_nt)} nT "
                  f"+- {_fmt(m.std_error_nt)} nT (standard error, {m.n} readings)",
                  code=Reason.SITE_FIELD_MEASURED, device=self.name, **m.as_data())
        self.source.check_measured(plan_name, points, m.vector_nt)
        return m

    def recheck(self, log_event: Callable, step_c: float) -> FieldMeasurement:
        """Measure again at a temperature step; record the change; Hold when it exceeds the limit."""
        assert self.start is not None, "measure_at_start first"
        m = self.measure()
        change = m.vector_nt - self.start.vector_nt
        size, limit = float(np.linalg.norm(change)), self.source.drift_max_nt()
        what = self.source.measured_name
        message = (f"{what} at {step_c:g} degC moved {size:.1f} nT since the start {_fmt(change)} nT "
                   f"(limit {limit:g} nT)")
        drifted = size > limit
        code = Reason.SITE_FIELD_DRIFT if drifted else Reason.SITE_FIELD_CHECKED
        log_event(Kind.SITE_FIELD, message, code=code, device=self.name, level="WARNING" if drifted else None,
                  change_nt=[float(c) for c in change], change_size_nt=size, limit_nt=limit, **m.as_data())
        if drifted:
            raise Hold(f"{message}: the references of this run would be off by that much",
                       code=Reason.SITE_FIELD_DRIFT, device=self.name)
        self._use_if_significant(m)
        return m

    def _use_if_significant(self, m: FieldMeasurement) -> None:
        """Keep the value in use unless `m` differs from it by more than their noise: averaging away nothing
        real, re-using a value also keeps each step's reference free of fresh measurement noise."""
        noise = np.sqrt(np.square(m.std_error_nt) + np.square(self.in_use.std_error_nt))
        if np.any(np.abs(m.vector_nt - self.in_use.vector_nt) > SIGNIFICANT * noise):
            self.in_use = m

    def check_at_end(self, log_event: Callable) -> FieldMeasurement | None:
        """After the last point (the field source already at its safe setting): one more measurement, so
        the drift over the whole run is on record. Never holds: the run is over; a fault is logged."""
        try:
            m = self.measure()
        except ERRORS as exc:
            log_event(Kind.SITE_FIELD, f"{self.source.measured_name} not measured at the end: {exc}",
                      code=Reason.SITE_FIELD_CHECKED, device=self.name, level="WARNING")
            return None
        finally:
            self.rig.field_source.safe_state()  # back where the engine left it
        change = m.vector_nt - self.start.vector_nt
        log_event(Kind.SITE_FIELD, f"{self.source.measured_name} at the end moved "
                  f"{float(np.linalg.norm(change)):.1f} nT since the start {_fmt(change)} nT",
                  code=Reason.SITE_FIELD_CHECKED, device=self.name,
                  change_nt=[float(c) for c in change], change_size_nt=float(np.linalg.norm(change)),
                  **m.as_data())
        return m


def reference_calibrations(station, campaign, info: dict | None) -> dict:
    """The reference magnetometers' calibrations for a run, their files relative to the station file
    (on a resume: the station path the session recorded, `info`)."""
    if not station.reference_magnetometers:
        return {}
    if campaign is not None:
        return load_reference_calibrations(station, campaign.station_path, campaign.station_text)
    assert info is not None
    return load_reference_calibrations(station, info.get("station_path") or ".", info["station_text"])


def measure_for_run(runner, session, calibrations: dict) -> None:
    """Before the first field is set: the reference magnetometer measures the ambient / site field that
    every reference of the run uses, and the plan's limits are checked with it. A failure here is
    recorded in the session as how the run ended, then raised."""
    from rig.fieldsources.fieldmaths import reference_for

    try:
        runner.site = SiteFieldMonitor(runner.rig, calibrations, settle_s=runner.plan.settle_s)
        measured = runner.site.measure_at_start(session.log_event, runner.plan.name, runner.points)
        runner.reference = reference_for(runner.rig.station, measured.vector_nt)
    except ERRORS as exc:
        session.log_event(Kind.FAULT, str(exc), code=code_of(exc), level="ERROR", device=device_of(exc))
        session.finish(FAILED, str(exc), code=code_of(exc))
        raise
