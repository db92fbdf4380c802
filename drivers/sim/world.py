"""The simulated physical truth that every simulator reads and every Modbus write drives.

- Field in the lab frame: coil matrix x coil currents + ambient field, when the coils are the field source;
  the coil matrix is the true one (3x3, nT/A) at the centre and, with a coil geometry, the true one at
  each DUT's own position (drivers/sim/coilfield.py). Or the site field rotated into the table frame by
  the turntable angles, through the table's true axes (tilts, zero offsets: TableAxes). Either may drift
  slowly and steadily (`ambient_drift_nt_per_s`), as a lab's field does when something nearby moves.
- Chamber air follows its setpoint at a limited ramp rate; each DUT's element temperature lags the air
  with its own time constant (first order). What the DUT's temperature sensors report (the TMP117 beside
  it, its own die sensor) lags the element by `sensor_lag_s` (first order, as a probe glued on the board
  lags the sensing element); 0 (the default) reports the element's own temperature.
- Each DUT has known calibration errors of the T24 form, B = (S + tau K) h + b + tau kb, plus a bridge
  offset that a SET/RESET pair cancels and that drifts with temperature, and white noise.

State is advanced lazily to `clock.now()` on every access, so simulated time may jump by hours.
Thread-safe: Modbus servers and the pty firmware run in their own threads.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np

from calib.synthetic import random_t24_params
from drivers.clock import Clock
from drivers.sim.coilfield import CoilGeometry, coil_matrix_at
from drivers.turntable import rotation_deg

MAX_THERMAL_STEP_S = 2.0  # integration sub-step; the lag model is exact within a step of constant air


@dataclass
class DutTruth:
    """The injected calibration errors of one DUT (absolute-tau T24 convention, tau in degC)."""

    S: np.ndarray  # 3x3, dimensionless
    K: np.ndarray  # 3x3, per degC
    b_nt: np.ndarray  # 3
    kb_nt_per_c: np.ndarray  # 3
    bridge_offset_nt: np.ndarray = field(default_factory=lambda: np.zeros(3))  # at 25 degC
    bridge_offset_tc_nt_per_c: np.ndarray = field(default_factory=lambda: np.zeros(3))
    noise_nt: float = 0.0  # white noise per axis, RMS
    thermal_lag_s: float = 600.0  # DUT temperature time constant against the chamber air
    mount: np.ndarray = field(default_factory=lambda: np.eye(3))  # lab frame -> sensor frame rotation
    sensor_lag_s: float = 0.0  # the reported temperature lags the element's by this time constant
    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # where it sits in the coil set

    def field_from_raw(self, h_nt: np.ndarray, temp_c: float) -> np.ndarray:
        """The T24 model itself: true field from a raw reading."""
        return (self.S + temp_c * self.K) @ h_nt + self.b_nt + temp_c * self.kb_nt_per_c

    def raw_from_field(self, field_nt: np.ndarray, temp_c: float) -> np.ndarray:
        """Noise-free raw reading (offset-cancelled) that the T24 model maps to `field_nt`."""
        return np.linalg.solve(self.S + temp_c * self.K, field_nt - self.b_nt - temp_c * self.kb_nt_per_c)

    def bridge_offset_at(self, temp_c: float) -> np.ndarray:
        return self.bridge_offset_nt + (temp_c - 25.0) * self.bridge_offset_tc_nt_per_c

    @classmethod
    def random(cls, rng: np.random.Generator, *, noise_nt: float = 20.0, thermal_lag_s: float = 600.0):
        """Errors of the size an AMR datasheet allows (calib.synthetic.random_t24_params), then a bridge
        offset of a few uT drifting some 10 nT/degC."""
        p = random_t24_params(rng)
        return cls(
            S=p["S"],
            K=p["K"],
            b_nt=p["b_nt"],
            kb_nt_per_c=p["kb_nt_per_c"],
            bridge_offset_nt=rng.normal(0, 2000, 3),
            bridge_offset_tc_nt_per_c=rng.normal(0, 20, 3),
            noise_nt=noise_nt,
            thermal_lag_s=thermal_lag_s,
        )


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


@dataclass
class _Dut:
    truth: DutTruth
    temp_c: float  # the element's
    sensor_c: float = math.nan  # what its temperature sensors report

    def __post_init__(self):
        if math.isnan(self.sensor_c):
            self.sensor_c = self.temp_c


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
        ramp_c_per_min: float = 3.0,
        turntable_rate_deg_s: float = 20.0,
        seed: int = 0,
        ambient_drift_nt_per_s=(0.0, 0.0, 0.0),
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
        self.rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._t = clock.now()
        # chamber
        self.air_c = air_c
        self.setpoint_c = air_c
        self.ramp_c_per_min = ramp_c_per_min
        self.chamber_alarm = False
        self.chamber_running = True
        # coils
        self.coil_currents_a = np.zeros(3)
        self.coils_enabled = False
        # turntable
        self.table_deg = np.zeros(2)  # az, el
        self.table_target_deg = np.zeros(2)
        self.turntable_rate_deg_s = turntable_rate_deg_s
        self.table_fault = False
        # DUTs and fixed temperature probes
        self.duts: dict[str, _Dut] = {}
        # the fault schedules of the simulated devices, by device name (drivers/sim/faults.py)
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
                step = self.ramp_c_per_min / 60.0 * dt
                delta = self.setpoint_c - self.air_c
                self.air_c += max(-step, min(step, delta))
            for d in self.duts.values():
                d.temp_c = self.air_c + (d.temp_c - self.air_c) * math.exp(-dt / d.truth.thermal_lag_s)
                lag = d.truth.sensor_lag_s
                d.sensor_c = d.temp_c + (d.sensor_c - d.temp_c) * math.exp(-dt / lag) if lag > 0 else d.temp_c
            t += dt
        self._t = now

    def _advance_table(self, dt: float) -> None:
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
            self.duts[name] = _Dut(truth, self.air_c if temp_c is None else temp_c)
            self._coil_matrix[name] = coil_matrix_at(self.coil_constants, self.coil_geometry,
                                                     truth.position_m)

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
            return self.duts[dut].truth.mount @ self.lab_field_nt(dut)

    def dut_raw_nt(self, dut: str, polarity: int = 1, noisy: bool = True) -> np.ndarray:
        """What the DUT's bridges output, in nT: polarity x h + bridge offset + noise.

        polarity is +1 after a SET pulse and -1 after a RESET pulse, so (out_set - out_reset)/2 = h.
        """
        with self._lock:
            self._advance()
            d = self.duts[dut]
            h = d.truth.raw_from_field(d.truth.mount @ self.lab_field_nt(dut), d.temp_c)
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
            if self.field_source == "coils":
                currents = self.coil_currents_a if self.coils_enabled else np.zeros(3)
                currents = currents * (1.0 + self.coil_nonlinearity_per_a * np.abs(currents))
                matrix = self.coil_constants if dut is None else self._coil_matrix[dut]
                return matrix @ currents + self.ambient_nt + self.drift_nt()
            return self.turntable_axes.rotation(*self.table_deg).T @ (self.site_field_nt + self.drift_nt())

    def set_coil_currents(self, currents_a, enabled: bool = True) -> None:
        with self._lock:
            self._advance()
            self.coil_currents_a = np.asarray(currents_a, float).copy()
            self.coils_enabled = enabled

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
