"""The input quantities of a coil station's reference field in a calibration's budget
(rig/budget/run_inputs.py asks the station's field source for them), for one DUT: the field at each of its
samples is B = M(r) I + ambient, from the sample's currents I, and every source below moves it linearly
(calib.uncertainty.propagation):

- coil matrix: the centre matrix's commissioning covariance (else the declared `constants_uncertainty_ppm`
  of each element's column); shared by every DUT of the campaign;
- reference magnetometer (and its temperature): what it measured (the commissioned matrix, the ambient)
  carries its calibration's error (rig/budget/run_inputs.py RunInputs.reference_sources);
- ambient: the run's best estimate from all its measurements and its covariance (rig/reference/ambient.py);
- ambient gradient: the lab field between the reference magnetometer and the DUT: measured by the
  commissioning's places and other reference magnetometers (carried into the references; the line its
  covariance), else `ambient_gradient_nt_per_m`;
- position, coil geometry, coil loops: the DUT's place, the loops' sizes and spacings, and each loop's place,
  lean and turns (rig/fieldsources/coils/loops.py), within their tolerances (rectangular);
- current source: none where the matrix and the measured ambient are both referred to the read-back
  currents the run uses (their gain and offset errors cancel); else its read-back's gain and offset error,
  measured at commissioning against the commanded currents the matrix was fitted to, else
  `current_accuracy` from its datasheet (rectangular);
- coil non-linearity, coil hysteresis, coil drift between repeats: as the commissioning's settings show them
  (rig/fieldsources/coils/commissioned.py);
- coil drift since commissioning: the commissioning's age times `constants_drift_ppm_per_year`.
Where a source cannot be stated, a note says so (never a silent zero).
"""

from __future__ import annotations

import numpy as np

from calib.uncertainty.propagation import InputSource, matrix_source
from rig.fieldsources.ambientlines import ambient_source, by_position, stated_gradient_source
from rig.fieldsources.coils import commissioned
from rig.fieldsources.coils.geometry import pair_field, rotation_between
from rig.fieldsources.coils.loops import loop_sensitivity

POSITION_STEP_MM = 0.5


def _rectangular(half_widths) -> np.ndarray:
    """The covariance of independent rectangular inputs of these half-widths."""
    return np.diag(np.asarray(half_widths, float) ** 2 / 3.0)


class CoilChain:
    """The sources of a coil station for one DUT. The coil matrix where the DUT sits moves with the centre
    matrix, the position and the geometry smoothly and very little over their uncertainties, so its
    sensitivities to them are taken once (central differences)."""

    def __init__(self, run, dut: str, ds):
        self.run = run
        self.source = run.station.field_source
        self.times = ds.columns["t"]
        config = run.station.dut(dut)
        self.position = np.zeros(3) if config.position_mm is None else np.asarray(config.position_mm, float)
        self.tolerance_mm = config.position_tolerance_mm
        self.centre = np.asarray(self.source.constants, float)
        self.matrix = self.source.matrices_at({dut: tuple(self.position)})[dut]  # as the run made its refs
        self.ambient = self._ambient_of(run, ds)
        # the measured gradient's share of the ambient where the DUT sits, as the run's references added it
        offset = self.source.gradient_offsets_nt({dut: tuple(self.position)},
                                                 run.station.ambient_position_mm()).get(dut, 0.0)
        self.currents = np.linalg.solve(self.matrix, (ds.ref_nt - self.ambient - offset).T).T
        self.measured = self.source.needs_measurement() and bool(run.site)
        self.by_centre = self._centre_sensitivity()

    def _ambient_of(self, run, ds) -> np.ndarray:
        """The ambient in `ds`'s references: the run's best estimate (a refined dataset, RunInputs.refined),
        else what each point recorded, else the station's."""
        recorded = run.recorded_ambient(ds)
        if recorded is not None:
            return recorded if run.ambient is None else run.ambient.at(ds.columns["t"])
        stated = self.source.ambient_nt
        return np.broadcast_to(np.zeros(3) if isinstance(stated, str) else np.asarray(stated, float),
                               (len(ds), 3))

    def _matrix_at(self, centre, position, geometry=None) -> np.ndarray:
        geometry = geometry or self.source.geometry
        if geometry is None or not np.any(position):
            return centre
        return geometry.matrices_at(centre, [position])[0]

    def _matrix_with_geometry(self, d: np.ndarray) -> np.ndarray:
        g = self.source.geometry
        drawn = g.model_copy(update={"size_m": tuple(np.add(g.size_m, d[:3])),
                                     "spacing_m": tuple(np.add(g.spacing_m, d[3:]))})
        return self._matrix_at(self.centre, self.position, drawn)

    def _centre_sensitivity(self, step: float = 1.0) -> np.ndarray:
        """(9,3,3): d(matrix at the DUT)/d(centre matrix entry, row-major). Column j of the matrix at a
        point follows column j of the centre matrix alone (geometry.coil_matrix_at), so each column's
        three entries are moved together in one evaluation of its pair's field."""
        out = np.zeros((9, 3, 3))
        geometry = self.source.geometry
        if geometry is None or not np.any(self.position):
            for k in range(9):
                out[k, k // 3, k % 3] = 1.0
            return out
        point = self.position / 1000.0
        for j in range(3):
            shape, size, spacing = geometry.shape, geometry.size_m[j], geometry.spacing_m[j]
            centre = pair_field(shape, j, size, spacing, np.zeros((1, 3)))[0]
            moved = np.repeat(self.centre[:, j][None], 6, axis=0)
            for i in range(3):
                moved[2 * i, i] += step
                moved[2 * i + 1, i] -= step
            rots = np.array([rotation_between(np.eye(3)[j], c / np.linalg.norm(c)) for c in moved])
            scale = np.linalg.norm(moved, axis=1) / np.linalg.norm(centre)
            field = pair_field(shape, j, size, spacing, np.einsum("dji,j->di", rots, point))
            columns = scale[:, None] * np.einsum("dij,dj->di", rots, field)
            for i in range(3):
                out[3 * i + j, :, j] = (columns[2 * i] - columns[2 * i + 1]) / (2 * step)
        return out

    @staticmethod
    def _sensitivity(matrix_of, n: int, step: float) -> np.ndarray:
        """(n,3,3): d(matrix)/d(input k), by central differences of `matrix_of(change)`."""
        out = np.empty((n, 3, 3))
        for k in range(n):
            d = np.zeros(n)
            d[k] = step
            out[k] = (matrix_of(d) - matrix_of(-d)) / (2 * step)
        return out

    def _columns(self, scale: float) -> np.ndarray:
        """(N,3,3): the field of coil j alone at every sample (M(r)[:, j] I_j) times `scale`: the change for
        a relative error of 1 / scale in coil j's field."""
        return np.einsum("ij,nj->nij", self.matrix, self.currents) * scale

    # --- the sources ---------------------------------------------------------------------------------
    def sources(self, notes: list[str]) -> list[InputSource]:
        out = [self._coil_matrix()]
        com = self.source.commissioned
        if com is not None or self.measured:
            measured = (self.currents @ self.matrix.T if com is not None else 0.0) + \
                (self.ambient if self.measured else 0.0)
            out += self.run.reference_sources(measured * np.ones((len(self.currents), 3)), notes)
        if self.measured:
            out.append(self._ambient())
            out += self._gradient(notes)
        else:
            notes.append("ambient as stated in the station: its uncertainty is not known (0 taken); "
                         "ambient_nt: measure states it")
        out += self._places(notes)
        out += self._current_source(notes)
        if com is not None:
            out += self._commissioned(com, notes)
        return [s for s in out if s is not None]

    def _coil_matrix(self) -> InputSource:
        com = self.source.commissioned
        if com is not None:
            sigma = np.asarray(com.covariance, float)[:9, :9]
            origin = f"commissioned {com.record.created_utc} ({com.path.name}): its covariance"
        else:
            ppm = self.source.constants_uncertainty_ppm
            scale = ppm * 1e-6 * np.linalg.norm(self.centre, axis=0)
            sigma = np.diag(np.tile(scale**2, 3))
            origin = f"declared, {ppm:g} ppm per element of its column: not commissioned"
        return matrix_source("coil matrix", self.currents, self.by_centre, sigma, origin=origin,
                             shared="coil matrix")

    def _ambient(self) -> InputSource:
        """The run's ambient estimate where the reference measured it (rig/reference/ambient.py)."""
        return ambient_source(self.run.ambient, self.times, "ambient")

    def _gradient(self, notes: list[str]) -> list[InputSource]:
        """The lab field's gradient between the reference magnetometer that measured the ambient and the
        DUT: B_i changes by G_ij (r_dut - r_ref)_j. Measured at commissioning (the ambient at its places) the
        references carry it, and its covariance is the line; else every G_ij within
        +-ambient_gradient_nt_per_m."""
        bound = self.source.ambient_gradient_nt_per_m
        offset_m = (self.position - self.run.reference_position_mm()) / 1000.0
        if not np.any(offset_m):
            return []
        measured = self.source.measured_gradient
        if measured is not None:  # its five independent components (gradientfit.py)
            unseen = "" if not measured.unidentified else \
                f"; {', '.join(measured.unidentified)} at the stated +-{measured.prior_nt_per_m:g} nT/m"
            a = np.broadcast_to(by_position(offset_m), (len(self.times), 3, 5))
            return [InputSource("ambient gradient", np.asarray(measured.covariance, float), ref_nt=a,
                                shared="ambient gradient",
                                origin=f"measured at commissioning from the ambient at {measured.places} "
                                "places (the reference's and other reference magnetometers'), carried "
                                f"into the references: its covariance{unseen}")]
        if bound is None:
            notes.append(f"ambient gradient over the {np.linalg.norm(offset_m) * 1000:.0f} mm between the "
                         "reference magnetometer and the DUT: not stated (field_source."
                         "ambient_gradient_nt_per_m), not in the budget")
            return []
        return [stated_gradient_source(np.broadcast_to(offset_m, (len(self.times), 3)), bound)]

    def _places(self, notes: list[str]) -> list[InputSource]:
        """The DUT's position, the loops' sizes and spacings, and each loop's place, lean and turns."""
        geometry = self.source.geometry
        if geometry is None:
            if np.any(self.position):
                notes.append("no coil geometry: the field at the DUT's position is taken as the centre's")
            return []
        out = []
        if self.tolerance_mm > 0:
            moved = self.position + np.concatenate([np.eye(3), -np.eye(3)]) * POSITION_STEP_MM
            matrices = geometry.matrices_at(self.centre, moved)
            per_mm = (matrices[:3] - matrices[3:]) / (2 * POSITION_STEP_MM)
            out.append(matrix_source("position", self.currents, per_mm,
                                     _rectangular(np.full(3, self.tolerance_mm)), distribution="rectangular",
                                     origin=f"+-{self.tolerance_mm:g} mm"))
        if geometry.tolerance_mm > 0:
            by_geometry = self._sensitivity(self._matrix_with_geometry, 6, 0.5e-3)
            out.append(matrix_source("coil geometry", self.currents, by_geometry,
                                     _rectangular(np.full(6, geometry.tolerance_mm / 1000.0)),
                                     distribution="rectangular", shared="coil geometry",
                                     origin=f"sizes and spacings +-{geometry.tolerance_mm:g} mm"))
        com = self.source.commissioned
        loops = None if com is None else com.record.coils.loops
        if np.any(self.position) and loops is not None:
            out.append(matrix_source(
                "coil loops", self.currents, loop_sensitivity(self.centre, geometry, self.position),
                np.asarray(loops.covariance, float), shared="coil loops",
                origin=f"each of the 6 loops' place, lean and turns fitted to the matrices at the centre and "
                f"{len(com.record.coils.places)} place(s) ({com.path.name}): their covariance"))
        elif np.any(self.position):
            half = np.tile([geometry.tolerance_mm] * 3 + [geometry.tilt_tolerance_deg,
                                                          geometry.turns_tolerance_ppm], 6)
            keep = half > 0
            if keep.any():
                by_loop = loop_sensitivity(self.centre, geometry, self.position)[keep]
                out.append(matrix_source(
                    "coil loops", self.currents, by_loop, _rectangular(half[keep]),
                    distribution="rectangular", shared="coil loops", origin=f"each of the 6 loops' place "
                    f"+-{geometry.tolerance_mm:g} mm, lean +-{geometry.tilt_tolerance_deg:g} deg, turns "
                    f"+-{geometry.turns_tolerance_ppm:g} ppm"))
        return out

    def _current_source(self, notes: list[str]) -> list[InputSource]:
        """The read-back currents' gain (ppm) and offset (mA) error per coil: measured at commissioning,
        else stated from the datasheet, else a note."""
        com = self.source.commissioned
        offsets = np.einsum("ij,nj->nij", self.matrix, np.ones_like(self.currents)) * 1e-3  # per mA
        a = np.concatenate([self._columns(1e-6), offsets], axis=2)  # (N,3,6): per ppm, per mA
        measured = None if com is None else com.record.coils.current_readback
        if self._referred_to_readback(com):
            notes.append("current source: the commissioned matrix and the run's ambient are both referred "
                         "to its read-back currents, so the read-back's gain and offset errors cancel; its "
                         "noise is in the fit's residual")
            return []
        if measured is not None:
            sigma = commissioned.readback_covariance(measured.model_dump())
            return [InputSource("current source", sigma, ref_nt=a, shared="current source",
                                origin=f"read-back against commanded, measured at commissioning "
                                f"{com.record.created_utc} (u^2 + error^2)")]
        stated = self.source.current_accuracy
        if stated is None:
            notes.append("current source: its read-back's accuracy is neither measured at commissioning nor "
                         "stated (field_source.current_accuracy), not in the budget")
            return []
        half = np.concatenate([np.broadcast_to(stated.gain_ppm, 3), np.broadcast_to(stated.offset_ma, 3)])
        return [InputSource("current source", _rectangular(half), ref_nt=a, distribution="rectangular",
                            shared="current source", origin="datasheet: gain +-" + _fmt(stated.gain_ppm)
                            + " ppm, offset +-" + _fmt(stated.offset_ma) + " mA")]

    def _referred_to_readback(self, com) -> bool:
        """Whether the matrix was fitted against read-back currents and every ambient measurement of the
        run had the read-back currents' field taken out (a stated ambient: none measured)."""
        if com is None or com.record.coils.fitted_to != "readback":
            return False
        return not self.measured or all("source_field_nt" in m for m in self.run.site)

    def _commissioned(self, com, notes: list[str]) -> list[InputSource]:
        """What the commissioning's settings show beyond the matrix, and its age."""
        settings, section, out = com.record.settings, com.record.coils, []
        when = f"commissioning {com.record.created_utc}"
        nonlinear = commissioned.nonlinearity(settings)
        if nonlinear is not None:
            _, sigma, absorbed = nonlinear
            out.append(InputSource("coil non-linearity", sigma, shared="coil non-linearity",
                                   ref_nt=commissioned.nonlinearity_sensitivity(self.currents, absorbed),
                                   origin=f"{when}: quadratic and cubic terms of every coil (u^2 + b^2)"))
        hysteresis = commissioned.hysteresis(settings)
        if hysteresis is not None:
            _, sigma = hysteresis
            out.append(InputSource("coil hysteresis", sigma, shared="coil hysteresis",
                                   ref_nt=commissioned.hysteresis_sensitivity(self._directions()),
                                   origin=f"{when}: field step between rising and falling currents "
                                   "(u^2 + b^2)"))
        drift = commissioned.repeat_drift(settings, section.repeats)
        if drift is not None:
            out.append(matrix_source("coil drift between repeats", self.currents, self.by_centre,
                                     np.diag(drift), shared="coil drift between repeats",
                                     origin=f"{when}: the matrix's scatter between its {section.repeats} "
                                     "repeats beyond their noise"))
        if nonlinear is None or hysteresis is None or drift is None:
            notes.append(f"{when}: its settings do not show the coils' non-linearity, hysteresis and drift "
                         "between repeats (too few settings, or one repeat): not in the budget")
        out += self._age_drift(com, notes)
        return out

    def _age_drift(self, com, notes: list[str]) -> list[InputSource]:
        rate = self.source.constants_drift_ppm_per_year
        age_days = max(0.0, self.run.age_days(com))
        if rate is None:
            notes.append(f"coil constants' drift over the commissioning's {age_days:.0f} days: no rate "
                         "stated (field_source.constants_drift_ppm_per_year), not in the budget")
            return []
        half = rate * age_days / 365.25
        if half <= 0:
            return []
        return [InputSource("coil drift since commissioning", _rectangular(np.full(3, half)),
                            ref_nt=self._columns(1e-6), distribution="rectangular",
                            shared="coil drift since commissioning",
                            origin=f"{age_days:.0f} days x +-{rate:g} ppm/year")]

    def _directions(self) -> np.ndarray:
        """(N,3): the direction of each coil's last current change into every sample's point (in time
        order; the coils start from 0 A)."""
        order = np.argsort(self.times, kind="stable")
        rounded = np.round(self.currents[order], 6)
        starts = np.flatnonzero(np.r_[True, np.any(np.diff(rounded, axis=0) != 0, axis=1)])
        s = commissioned.directions(rounded[starts])
        per_sample = s[np.searchsorted(starts, np.arange(len(order)), side="right") - 1]
        out = np.empty_like(per_sample)
        out[order] = per_sample
        return out


def _fmt(value) -> str:
    values = np.atleast_1d(np.asarray(value, float))
    return f"{values[0]:g}" if values.size == 1 else "(" + ", ".join(f"{v:g}" for v in values) + ")"
