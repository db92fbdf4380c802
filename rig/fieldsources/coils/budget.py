"""The sources of a coil station's reference field in a calibration's budget (rig/reference/budget.py asks
the station's field source for them): the coil matrix (commissioned or declared), the reference
magnetometer that commissioned it or measured the ambient, the ambient, each DUT's position and the coil
geometry. Each draws other reference fields for one DUT's samples, B' = M'(r) I + a', from each sample's
currents I."""

from __future__ import annotations

import functools

import numpy as np

from calib.uncertainty import Draw, Source


class CoilChain:
    """The sources of a coil station, for one DUT: each draws other reference fields for its samples,
    B' = M'(r) I + a', from each sample's currents I. The coil matrix where the DUT sits moves with the
    centre matrix, the position and the geometry smoothly and very little over their uncertainties, so
    its sensitivities to them are taken once (central differences) and every draw is a sum of them."""

    def __init__(self, run, dut: str, ds):
        self.run = run
        self.source = run.station.field_source
        self.times = ds.columns["t"]
        config = run.station.dut(dut)
        self.position = np.zeros(3) if config.position_mm is None else np.asarray(config.position_mm, float)
        self.tolerance_mm = config.position_tolerance_mm
        self.centre = np.asarray(self.source.constants, float)
        self.matrix = self._matrix_at(self.centre, self.position)
        self.ambient = self._ambient_of(run, ds)
        self.currents = np.linalg.solve(self.matrix, (ds.ref_nt - self.ambient).T).T
        self.measured = self.source.needs_measurement() and bool(run.site)
        self.by_centre = self._sensitivity(
            lambda d: self._matrix_at(self.centre + d.reshape(3, 3), self.position), 9, 1.0)
        if self.source.geometry is not None:
            self.by_position = self._sensitivity(lambda d: self._matrix_at(self.centre, self.position + d),
                                                 3, 0.5)
            self.by_geometry = self._sensitivity(self._matrix_with_geometry, 6, 0.5e-3)

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

    @staticmethod
    def _sensitivity(matrix_of, n: int, step: float) -> np.ndarray:
        """(n,3,3): d(matrix)/d(input k), by central differences of `matrix_of(change)`."""
        out = np.empty((n, 3, 3))
        for k in range(n):
            d = np.zeros(n)
            d[k] = step
            out[k] = (matrix_of(d) - matrix_of(-d)) / (2 * step)
        return out

    def _with_change(self, sensitivity: np.ndarray, change: np.ndarray) -> Draw:
        return Draw(ref_nt=self.currents @ np.tensordot(change, sensitivity, axes=1).T)

    def sources(self, notes: list[str]) -> list[Source]:
        source, com = self.source, self.source.commissioned
        if com is not None:
            out = [Source("coil matrix", self._commissioned_draw, f"commissioned {com.record.created_utc}")]
        else:
            out = [Source("coil matrix", self._declared_draw,
                          f"declared, {source.constants_uncertainty_ppm:g} ppm per element: "
                          "not commissioned")]
        if self.run.reference_cal is not None and (com is not None or self.measured):
            out.append(Source("reference magnetometer", self._reference_draw,
                              "its calibration's stated uncertainty"))
        if self.measured:
            model = self.run.ambient
            drift = " with a drift" if model.drifting else ""
            out.append(Source("ambient", self._ambient_draw, f"measured {model.n} time(s){drift}"))
        else:
            notes.append("ambient as stated in the station: its uncertainty is not known (0 taken)")
        if source.geometry is None:
            if np.any(self.position):
                notes.append("no coil geometry: the field at the DUT's position is taken as the centre's")
            return out
        if self.tolerance_mm > 0:
            out.append(Source("position", self._position_draw, f"+-{self.tolerance_mm:g} mm"))
        if source.geometry.tolerance_mm > 0:
            out.append(Source("coil geometry", self._geometry_draw, f"+-{source.geometry.tolerance_mm:g} mm"))
        return out

    @functools.cached_property
    def _matrix_cholesky(self) -> np.ndarray:
        return np.linalg.cholesky(self.source.commissioned.covariance[:9, :9])

    def _commissioned_draw(self, rng: np.random.Generator) -> Draw:
        return self._with_change(self.by_centre, self._matrix_cholesky @ rng.normal(0.0, 1.0, 9))

    def _declared_draw(self, rng: np.random.Generator) -> Draw:
        scale = self.source.constants_uncertainty_ppm * 1e-6 * np.linalg.norm(self.centre, axis=0)
        return self._with_change(self.by_centre, (rng.normal(0.0, 1.0, (3, 3)) * scale).ravel())

    def _reference_draw(self, rng: np.random.Generator) -> Draw:
        """What the reference measured (the commissioned matrix, the ambient) carries its error."""
        t, d = self.run.reference_transform(rng)
        off = t - np.eye(3)
        change = np.zeros_like(self.ambient)
        if self.source.commissioned is not None:
            change += (self.currents @ self.matrix.T) @ off.T
        if self.measured:
            change += self.ambient @ off.T + d
        return Draw(ref_nt=change)

    def _ambient_draw(self, rng: np.random.Generator) -> Draw:
        return Draw(ref_nt=self.run.ambient.draw_error(self.times, rng))

    def _position_draw(self, rng: np.random.Generator) -> Draw:
        return self._with_change(self.by_position, rng.uniform(-self.tolerance_mm, self.tolerance_mm, 3))

    def _geometry_draw(self, rng: np.random.Generator) -> Draw:
        tol_m = self.source.geometry.tolerance_mm / 1000.0
        return self._with_change(self.by_geometry, rng.uniform(-tol_m, tol_m, 6))
