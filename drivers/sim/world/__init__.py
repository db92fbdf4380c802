"""The simulated physical truth that every simulator reads and every Modbus write drives.

- Field in the lab frame: coil matrix x coil currents + ambient field, when the coils are the field source;
  the coil matrix is the true one (3x3, nT/A) at the centre and, with a coil geometry, the true one at
  each DUT's own position (drivers/sim/world/coilfield.py). Or the site field rotated into the table frame by
  the turntable angles, through the table's true axes (tilts, zero offsets: TableAxes). Either may drift
  slowly and steadily (`ambient_drift_nt_per_s`), as a lab's field does when something nearby moves.
- Chamber air follows its setpoint at a limited ramp rate; each DUT's element temperature lags the air
  with its own time constant (first order). What the DUT's temperature sensors report (the TMP117 beside
  it, its own die sensor) lags the element by `sensor_lag_s` (first order, as a probe glued on the board
  lags the sensing element); 0 (the default) reports the element's own temperature.
- Each DUT has known calibration errors of the T24 form, B = (S + tau K) h + b + tau kb, plus a bridge
  offset that a SET/RESET pair cancels and that drifts with temperature, and white noise.

Deviations from every one of these models, each off unless stated, live beside the physics they bend:
the DUT beyond T24 and the slow noise on its offset (drivers/sim/world/dutmodel.py; a DUT's place may also be
warmer than the air, `air_offset_c`), each coil loop on its own (coilfield.py), the current source's
errors (currentsource.py), the ambient's gradient and steps (labfield.py), and the chamber's real rate,
overshoot and heater and compressor fields (chamberair.py). This module composes them. Every random
process has its own generator from the seed (per DUT where it belongs to one), so the white noise's
draws, and so a world without deviations, stay exactly as they were.

State is advanced lazily to `clock.now()` on every access, so simulated time may jump by hours.
Thread-safe: Modbus servers and the pty firmware run in their own threads.
"""

from __future__ import annotations

import math
import threading
import zlib
from dataclasses import dataclass

import numpy as np

from drivers.clock import Clock
from drivers.sim.world.chamberair import ChamberAir, ChamberTruth
from drivers.sim.world.coilfield import CoilGeometry, LoopErrors, coil_matrix_at
from drivers.sim.world.currentsource import CurrentSource, CurrentSourceErrors
from drivers.sim.world.dutmodel import DutState, DutTruth
from drivers.sim.world.dutthermal import DutTemperatures
from drivers.sim.world.labfield import AmbientSteps, LabField
from drivers.turntable import rotation_deg

__all__ = ["DutTruth", "TableAxes", "World"]  # DutTruth lives in dutmodel.py; imported from here too

MAX_THERMAL_STEP_S = 2.0  # integration sub-step; the lag model is exact within a step of constant air


@dataclass(frozen=True)
class TableAxes:
    """How a real two-axis table differs from its drawing: its azimuth axis tilted (about x, then y), its
    elevation axis tilted towards the azimuth axis (about x), and the zero offsets of its encoders."""

    az_tilt_deg: tuple[float, float] = (0.0, 0.0)
    el_tilt_deg: float = 0.0
    zero_offsets_deg: tuple[float, float] = (0.0, 0.0)

    def rotation(self, az_deg: float, el_deg: float) -> np.ndarray:
        """Table frame -> lab frame at the commanded angles (the ideal table: rotation_deg)."""
        tilt = _rx(self.az_tilt_deg[0]) @ _ry(self.az_tilt_deg[1])
        el_axis = _rx(self.el_tilt_deg)
        turned = rotation_deg(az_deg + self.zero_offsets_deg[0], 0.0)
        return tilt @ turned @ el_axis @ _ry(el_deg + self.zero_offsets_deg[1]) @ el_axis.T


def _rx(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(deg: float) -> np.ndarray:
    return rotation_deg(0.0, deg)


# streams of the world's generators beside the white noise's (np.random.default_rng([seed, stream, ...]))
OFFSET_NOISE_STREAM, CURRENT_NOISE_STREAM, AMBIENT_STEP_STREAM, READ_BACK_STREAM = 1, 2, 3, 4


def _stream(seed: int, stream: int, name: str = "") -> np.random.Generator:
    return np.random.default_rng([seed, stream, zlib.crc32(name.encode())])


class World:
    """Physical truth of the simulated rig, on an injected clock."""

    def __init__(
        self,
        clock: Clock,
        *,
        field_source: str = "coils",  # "coils" or "turntable"
        ambient_nt=(0.0, 0.0, 0.0),
        coil_constants_nt_per_a=None,
        coil_geometry: CoilGeometry | tuple | None = None,  # or (shape, size_m, spacing_m)
        turntable_axes: TableAxes | tuple | None = None,  # or (az_tilt_deg, el_tilt_deg, zero_offsets_deg)
        coil_nonlinearity_per_a=(0.0, 0.0, 0.0),
        site_field_nt=(19148.0, 894.0, 45587.0),
        air_c: float = 22.0,
        ramp_c_per_min: float = 3.0,  # the fastest the air moves (the chamber's own, whatever it is told)
        turntable_rate_deg_s: float = 20.0,
        seed: int = 0,
        ambient_drift_nt_per_s=(0.0, 0.0, 0.0),
        chamber: ChamberTruth | None = None,  # the chamber's real rate, overshoot, heater, compressor
        current_source: CurrentSourceErrors | None = None,
        coil_loops: dict[int, LoopErrors] | None = None,  # by axis
        ambient_gradient_nt_per_m=None,  # 3x3, dB_i/dx_j
        ambient_steps: tuple[float, float] | None = None,  # (mean_interval_h, size_nt)
    ):
        self.clock = clock
        self.field_source = field_source
        self.ambient_nt = np.asarray(ambient_nt, float)
        self.coil_constants = (
            np.diag([50_000.0, 50_000.0, 50_000.0])
            if coil_constants_nt_per_a is None
            else np.asarray(coil_constants_nt_per_a, float)
        )
        if isinstance(coil_geometry, tuple):
            coil_geometry = CoilGeometry(*coil_geometry)
        self.coil_geometry = coil_geometry
        # a coil whose field is not linear in its current: B_j = M_j I_j (1 + n_j |I_j|) (saturation, heat)
        self.coil_nonlinearity_per_a = np.asarray(coil_nonlinearity_per_a, float)
        if isinstance(turntable_axes, tuple):
            turntable_axes = TableAxes(*turntable_axes)
        self.turntable_axes = turntable_axes or TableAxes()
        self._coil_matrix: dict[str, np.ndarray] = {}  # the true coil matrix at each DUT's position
        self.site_field_nt = np.asarray(site_field_nt, float)
        self.ambient_drift_nt_per_s = np.asarray(ambient_drift_nt_per_s, float)
        self._t0 = clock.now()  # the drift counts from here
        self.seed = seed
        self.rng = np.random.default_rng(seed)  # the DUTs' white noise
        self._lock = threading.RLock()
        self._t = clock.now()
        # chamber
        self.air_c = air_c
        self.setpoint_c = air_c
        self.ramp_c_per_min = ramp_c_per_min
        self.chamber = ChamberAir(chamber or ChamberTruth(), air_c, self._t, ramp_c_per_min)
        self.chamber_alarm = False
        self.chamber_running = True
        # coils
        self.coil_currents_a = np.zeros(3)
        self.coils_enabled = False
        self.coil_outputs_on = np.zeros(3, bool)
        self.coil_loops = coil_loops
        self.current_source = None
        if current_source is not None and not current_source.is_zero():
            self.current_source = CurrentSource(current_source, _stream(seed, READ_BACK_STREAM))
        self._centre_rng = _stream(seed, CURRENT_NOISE_STREAM)  # the current noise at the centre
        # the lab's field beyond a uniform, steady ambient
        gradient = ambient_gradient_nt_per_m if np.any(ambient_gradient_nt_per_m) else None
        steps = None
        if ambient_steps is not None and ambient_steps[1] > 0:
            steps = AmbientSteps(_stream(seed, AMBIENT_STEP_STREAM), self._t,
                                 mean_interval_h=ambient_steps[0], size_nt=ambient_steps[1])
        self.lab = None if gradient is None and steps is None else LabField(gradient, steps)
        # turntable
        self.table_deg = np.zeros(2)  # az, el
        self.table_target_deg = np.zeros(2)
        self.turntable_rate_deg_s = turntable_rate_deg_s
        self.table_fault = False
        # DUTs and fixed temperature probes
        self.duts: dict[str, DutState] = {}
        self._temps = DutTemperatures()  # every DUT's, advanced as one
        # the fault schedules of the simulated devices, by device name (drivers/sim/devices/faults.py)
        self.faults: dict[str, object] = {}

    # --- time -------------------------------------------------------------------------------------
    def _advance(self) -> None:
        now = self.clock.now()
        dt_total = now - self._t
        if dt_total <= 0:
            return
        self._advance_table(dt_total)
        t = 0.0
        while t < dt_total:
            dt = min(MAX_THERMAL_STEP_S, dt_total - t)
            if self.chamber_running:
                self.air_c = self.chamber.step(self.air_c, self.setpoint_c, self.ramp_c_per_min, dt)
            self._temps.step(self.air_c, dt)
            t += dt
        self._t = now

    def _advance_table(self, dt: float) -> None:
        if self.table_deg.tolist() == self.table_target_deg.tolist():  # at rest: every reading comes here
            return
        move = self.table_target_deg - self.table_deg
        reach = self.turntable_rate_deg_s * dt
        dist = float(np.max(np.abs(move)))
        if dist <= reach or dist == 0:
            self.table_deg = self.table_target_deg.copy()
        else:
            self.table_deg = self.table_deg + move * (reach / dist)

    # --- chamber ----------------------------------------------------------------------------------
    def set_chamber_setpoint(self, temp_c: float) -> None:
        with self._lock:
            self._advance()
            self.setpoint_c = float(temp_c)

    def set_chamber_ramp(self, c_per_min: float) -> None:
        with self._lock:
            self._advance()
            self.ramp_c_per_min = float(c_per_min)

    def chamber_air_c(self) -> float:
        with self._lock:
            self._advance()
            return self.air_c

    # --- DUTs -------------------------------------------------------------------------------------
    def add_dut(self, name: str, truth: DutTruth, temp_c: float | None = None) -> None:
        with self._lock:
            self._advance()
            start_c = self.air_c + truth.air_offset_c if temp_c is None else temp_c
            self.duts[name] = DutState(truth, self._temps, start_c, self._t,
                                       _stream(self.seed, OFFSET_NOISE_STREAM, name),
                                       _stream(self.seed, CURRENT_NOISE_STREAM, name))
            self._coil_matrix[name] = coil_matrix_at(self.coil_constants, self.coil_geometry,
                                                     truth.position_m, self.coil_loops)

    def dut_temp_c(self, name: str) -> float:
        """What the DUT's temperature sensors report (its element's, unless sensor_lag_s > 0)."""
        with self._lock:
            self._advance()
            return self.duts[name].sensor_c

    def element_temp_c(self, name: str) -> float:
        """The sensing element's own temperature (the tau of its T24 truth)."""
        with self._lock:
            self._advance()
            return self.duts[name].temp_c

    def true_field_nt(self, dut: str) -> np.ndarray:
        """True field in the DUT's sensor frame, nT."""
        with self._lock:
            self._advance()
            return self.duts[dut].truth.mount @ self._lab_field_nt(dut)

    def dut_raw_nt(self, dut: str, polarity: int = 1, noisy: bool = True) -> np.ndarray:
        """What the DUT's bridges output, in nT: polarity x h + bridge offset + noise.

        polarity is +1 after a SET pulse and -1 after a RESET pulse, so (out_set - out_reset)/2 = h.
        """
        with self._lock:
            self._advance()
            d = self.duts[dut]
            extra = d.extra_offset_nt(self._t)
            h = d.truth.raw_from_field(d.truth.mount @ self._lab_field_nt(dut), d.temp_c, extra)
            out = polarity * h + d.truth.bridge_offset_at(d.temp_c)
            if noisy and d.truth.noise_nt > 0:
                out = out + self.rng.normal(0, d.truth.noise_nt, 3)
            return out

    # --- field source -----------------------------------------------------------------------------
    def drift_nt(self) -> np.ndarray:
        """How far the ambient (coils) or the site field (turntable) has drifted since the start."""
        with self._lock:
            return self.ambient_drift_nt_per_s * (self.clock.now() - self._t0)

    def lab_field_nt(self, dut: str | None = None) -> np.ndarray:
        """The field where `dut` sits (lab frame; for a turntable, the table frame), or at the centre."""
        with self._lock:
            self._advance()
            return self._lab_field_nt(dut)

    def _lab_field_nt(self, dut: str | None) -> np.ndarray:
        """lab_field_nt with the lock held and the state advanced. Terms that are zero (no coil
        nonlinearity, no drift) are skipped, not added: every DUT reading comes through here."""
        if self.field_source == "coils":
            currents = self.coil_currents_a if self.coils_enabled else np.zeros(3)
            if self.current_source is not None and self.coils_enabled:
                rng = self._centre_rng if dut is None else self.duts[dut].current_rng
                currents = self.current_source.delivered_a(currents, self.coil_outputs_on, rng)
            if any(self.coil_nonlinearity_per_a.tolist()):  # (faster than ndarray.any on 3 numbers)
                currents = currents * (1.0 + self.coil_nonlinearity_per_a * np.abs(currents))
            matrix = self.coil_constants if dut is None else self._coil_matrix[dut]
            field = matrix @ currents + self.ambient_nt
            if any(self.ambient_drift_nt_per_s.tolist()):
                field = field + self.drift_nt()
            return field if not self._bent() else field + self._environment_nt(dut)
        turned = self.turntable_axes.rotation(*self.table_deg)
        site = self.site_field_nt + self.drift_nt()
        if self._bent():
            site = site + self._environment_nt(dut, turned)
        return turned.T @ site

    def _bent(self) -> bool:
        return self.lab is not None or self.chamber.makes_field

    def _environment_nt(self, dut: str | None, turned: np.ndarray | None = None) -> np.ndarray:
        """The lab's field beyond its ambient where `dut` sits: gradient, steps, heater and compressor.
        On a turntable (`turned`: table frame -> lab) its position is on the table, about the axes'
        crossing, and turns with it through the lab's gradient."""
        position = np.zeros(3) if dut is None else self.duts[dut].truth.position_m
        if turned is not None:
            position = turned @ position
        out = np.zeros(3) if self.lab is None else self.lab.field_nt(position, self._t)
        return out + self.chamber.field_nt(self._t) if self.chamber.makes_field else out

    def coil_readback_a(self, regulated_a: np.ndarray) -> np.ndarray:
        """What the coil controller's read-back registers show while it regulates to `regulated_a`."""
        with self._lock:
            if self.current_source is None:
                return regulated_a
            return self.current_source.reported_a(regulated_a, self.coil_outputs_on)

    def set_coil_currents(self, currents_a, enabled: bool = True, outputs_on=None) -> None:
        """The currents the controller regulates to; `outputs_on` (per channel, default: all as `enabled`)
        says which outputs drive (a current source's offset flows only in those)."""
        with self._lock:
            self._advance()
            self.coil_currents_a = np.asarray(currents_a, float).copy()
            self.coils_enabled = enabled
            self.coil_outputs_on = np.full(3, enabled) if outputs_on is None else np.asarray(outputs_on, bool)

    def set_turntable_target(self, az_deg: float, el_deg: float) -> None:
        with self._lock:
            self._advance()
            self.table_target_deg = np.array([az_deg, el_deg], float)

    def stop_turntable(self) -> None:
        with self._lock:
            self._advance()
            self.table_target_deg = self.table_deg.copy()

    def turntable_angles_deg(self) -> np.ndarray:
        with self._lock:
            self._advance()
            return self.table_deg.copy()

    def turntable_moving(self) -> bool:
        with self._lock:
            self._advance()
            return bool(np.any(self.table_deg != self.table_target_deg))
