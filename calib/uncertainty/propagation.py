"""Linear propagation of input uncertainties to a calibration (GUM, JCGM 100 §5: the law of propagation
with the full covariance of the inputs).

    source = InputSource("coil matrix", covariance, ref_nt=sensitivity, origin="commissioning 2024-05-01",
                         shared="coil matrix")
    lin = propagate_linear(ds, cal, [source, ...], grid=(fields_nt, temps_c))
    lin.covariance                 # (P,P) of the flat parameters (calib.uncertainty.linearise.ParamLayout),
                                   # all inputs
    lin.contributions              # each input's covariance and the RMS field error it causes (nT)
    lin.radius_nt                  # (G,): the 95 % radius of the calibrated field's 3-D error per grid point
    cross_covariance(lin_a, lin_b) # (Pa,Pb): two calibrations sharing input quantities

Sources of the usual shapes: `matrix_source` (a coil matrix, or its change with position or geometry, times
each sample's currents), `offset_source` (an ambient field), `temperature_source` (temperature changes as
columns times q) and `reference_source` (a reference magnetometer's calibration error in what it measured).

An input source is a set of input quantities q (Q of them) with covariance Sigma_q and the way they change
the data, linearly: the references by a_ref q (a_ref (N,3,Q): sample n's reference changes by
a_ref[n] @ q) and/or the temperatures by a_temp q (a_temp (N,Q)); and, for a model error the calibration
cannot follow (a term the model lacks), the true field at the grid points by a_grid q (a_grid (G,3,Q)).
The parameters then change by J q with J = d theta / d q (calib/uncertainty/linearise.py): exact for T24 and
T36 and reference changes (theta = G^-1 X^T W B), first order otherwise (P12, the scalar fit, temperature
changes); each contribution says which. Its
covariance is J Sigma_q J^T, and the fit's own noise adds sigma^2 G^-1 ("fit (statistical)"). Sources are
independent of each other unless they share input quantities: two calibrations whose sources name the
same `shared` quantities (the campaign's coil matrix, its ambient) covary by J_a Sigma_q J_b^T.

The calibrated field at a grid point (field, temperature) is made from the raw reading the calibration
maps to that field (calib.uncertainty.montecarlo.raw_for); its error is F dtheta, F = d field / d theta, less
the sources' direct effects a_grid q on the true field there: (F J - a_grid) q per source, so its covariance
is F C F^T from the sources without a direct effect plus (F J - a_grid) Sigma_q (F J - a_grid)^T from
those with one (3x3), and the radius holding 95 % of a Gaussian error with that covariance is the
expanded vector error at that point (calib.stats.distributions.gaussian_radius).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.errors import DataError
from calib.models import registry
from calib.stats.distributions import gaussian_radius
from calib.stats.student import effective_dof
from calib.uncertainty.linearise import ParamLayout, field_jacobian, linearised
from calib.uncertainty.montecarlo import raw_for
from calib.uncertainty.rowgroups import RowGroups

STATISTICAL = "fit (statistical)"
# of each unit part of q: normal, rectangular (a +- tolerance), two-point (+-1 with equal chance: a state
# that is one way or the other, as a thermal hysteresis at a point of use)
DISTRIBUTIONS = ("normal", "rectangular", "two-point")
Sensitivity = np.ndarray | RowGroups | Callable[[Dataset], np.ndarray | RowGroups] | None
GridSensitivity = np.ndarray | Callable[[np.ndarray, np.ndarray | None], np.ndarray] | None


@dataclass(frozen=True)
class Estimated:
    """Variances of some of a source's quantities that were estimated from few readings: the quantities
    `index` of q, the part `variance` of each one's variance so estimated (those quantities independent of
    the others), and the estimate's degrees of freedom (GUM G.3.3: readings less fitted constants). One
    Estimated is one estimate: quantities whose variances come from the same scatter go together, since
    they are off by the same factor."""

    index: np.ndarray
    variance: np.ndarray
    dof: float


@dataclass(frozen=True)
class InputSource:
    """Input quantities q ~ (0, covariance) and how they change the data (see the module doc)."""

    name: str
    covariance: np.ndarray  # Sigma_q (Q,Q): standard uncertainties squared, with their correlations
    # a_ref (N,3,Q) or its compact form calib.uncertainty.rowgroups.RowGroups (offsets per group of rows), or
    # a function of the dataset giving either
    ref_nt: Sensitivity = None
    temp_c: Sensitivity = None  # a_temp (N,Q), or a function of the dataset giving it
    distribution: str = "normal"  # of q = L v (L L^T = Sigma_q), v independent unit-variance entries
    origin: str = ""  # where Sigma_q comes from (a commissioning file, a datasheet, a tolerance)
    shared: str | None = None  # names the input quantities when other calibrations share them
    # a_grid (G,3,Q), or a function of the grid's raw readings (G,3) and temperatures (G,) or None giving
    # it: the direct effect on the true field at the grid points (a model error), beside any on the data
    field_nt: GridSensitivity = None
    # parts of Sigma_q estimated from few readings (Type A), with their degrees of freedom; the rest of
    # Sigma_q is taken as known (infinite degrees of freedom)
    estimated: tuple[Estimated, ...] = ()

    def sensitivities(self, ds: Dataset) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(a_ref (N,3,Q) or None, a_temp (N,Q) or None), checked against the dataset and Sigma_q."""
        cov = np.atleast_2d(np.asarray(self.covariance, float))
        q = cov.shape[0]
        if cov.shape != (q, q) or not np.allclose(cov, cov.T, rtol=1e-9, atol=0):
            raise DataError(f"source {self.name!r}: covariance must be a symmetric (Q,Q) matrix, "
                            f"got {cov.shape}")
        if self.distribution not in DISTRIBUTIONS:
            raise DataError(f"source {self.name!r}: distribution {self.distribution!r} (known: "
                            f"{', '.join(DISTRIBUTIONS)})")
        out = []
        wanted = (("ref_nt", self.ref_nt, (len(ds), 3, q)), ("temp_c", self.temp_c, (len(ds), q)))
        for what, given, shape in wanted:
            a = given(ds) if callable(given) else given
            if isinstance(a, RowGroups):  # compact: kept so, every consumer contracts it per group
                if a.shape != shape:
                    raise DataError(f"source {self.name!r}: {what} sensitivity has shape {a.shape}, "
                                    f"expected {shape}")
            elif a is not None:
                a = np.asarray(a, float)
                if a.shape != shape:
                    raise DataError(f"source {self.name!r}: {what} sensitivity has shape {a.shape}, "
                                    f"expected {shape}")
            out.append(a)
        if out[0] is None and out[1] is None and self.field_nt is None:
            raise DataError(f"source {self.name!r}: it changes neither the references, the temperatures nor "
                            "the true field")
        return out[0], out[1]

    def take(self, rows: np.ndarray) -> InputSource:
        """The source for the dataset's rows `rows` alone (ds.subset(rows)); a sensitivity given as a
        function of the dataset is asked of that subset in its turn."""

        def pick(a):
            if a is None or callable(a):
                return a
            return a.take(rows) if isinstance(a, RowGroups) else np.asarray(a, float)[rows]

        return replace(self, ref_nt=pick(self.ref_nt), temp_c=pick(self.temp_c))

    def grid_effect(self, grid_h_nt: np.ndarray, grid_temp_c: np.ndarray | None) -> np.ndarray | None:
        """a_grid (G,3,Q) at the grid's raw readings and temperatures, checked (None: no direct effect)."""
        if self.field_nt is None:
            return None
        a = self.field_nt(grid_h_nt, grid_temp_c) if callable(self.field_nt) else self.field_nt
        a = np.asarray(a, float)
        q = np.atleast_2d(np.asarray(self.covariance, float)).shape[0]
        if a.shape != (len(grid_h_nt), 3, q):
            raise DataError(f"source {self.name!r}: field sensitivity has shape {a.shape}, expected "
                            f"{(len(grid_h_nt), 3, q)}")
        return a


def matrix_source(name: str, currents_a: np.ndarray, by_quantity: np.ndarray, covariance,
                  **kw) -> InputSource:
    """A coil matrix's uncertainty: the field at each sample is M I, and M moves by sum_k q_k by_quantity[k]
    (by_quantity (Q,3,3), e.g. the unit matrices of its 9 entries, or its change per mm of position)."""
    a = np.einsum("kij,nj->nik", np.asarray(by_quantity, float), np.asarray(currents_a, float))
    return InputSource(name, np.asarray(covariance, float), ref_nt=a, **kw)


def offset_source(name: str, n: int, covariance, **kw) -> InputSource:
    """A field added to every reference (an ambient field): q is its 3 components."""
    return InputSource(name, np.asarray(covariance, float), ref_nt=np.broadcast_to(np.eye(3), (n, 3, 3)),
                       **kw)


def temperature_source(name: str, columns: np.ndarray, covariance, **kw) -> InputSource:
    """Temperature changes columns @ q (columns (N,Q): e.g. ones for an offset, T - 25 for a gradient)."""
    columns = np.asarray(columns, float)
    return InputSource(name, np.asarray(covariance, float), temp_c=columns.reshape(len(columns), -1), **kw)


def affine_map(cal: Calibration, temp_c: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(A, c) with cal.apply(h) = A h + c at temp_c (every model is affine in its reading)."""
    h = np.vstack([np.zeros(3), np.eye(3)])
    out = cal.apply(h, None if temp_c is None else np.full(4, float(temp_c)))
    return (out[1:] - out[0]).T, out[0]


def reference_source(name: str, measured_nt: np.ndarray, cal: Calibration, param_cov: np.ndarray,
                     temp_c: float | None, **kw) -> InputSource:
    """A reference magnetometer's calibration error. Its calibration maps its reading to A h + c; with its
    parameters off by dp the field it reported, B' (measured_nt (N,3): the fields it measured that went
    into the references), is off by dB = dT B' + dd, dT = dA A^-1, dd = dc - dT c (first order; A, c at
    its measuring temperature temp_c). The input quantities are its parameters (flat, in the order of
    cal.params) with covariance param_cov: its budget's covariance, else diag(u^2)."""
    layout = ParamLayout.of(cal.params)
    flat = layout.flatten(cal.params)
    a0, c0 = affine_map(cal, temp_c)
    a_inv = np.linalg.inv(a0)
    jac = np.empty((12, flat.size))  # d (vec dT, dd) / d p, central differences
    for j in range(flat.size):
        step = 1e-6 * (abs(flat[j]) + np.mean(np.abs(flat)) * 1e-3 + 1e-12)
        moved = []
        for sign in (1.0, -1.0):
            p = flat.copy()
            p[j] += sign * step
            a, c = affine_map(Calibration(cal.model, layout.unflatten(p), {}, cal.temp_ref_c), temp_c)
            d_t = (a - a0) @ a_inv
            moved.append(np.concatenate([d_t.ravel(), c - c0 - d_t @ c0]))
        jac[:, j] = (moved[0] - moved[1]) / (2 * step)
    measured = np.asarray(measured_nt, float)
    per_q = np.zeros((len(measured), 3, 12))  # dB_n for a unit change of (vec dT, dd)
    for i in range(3):
        per_q[:, i, 3 * i:3 * i + 3] = measured
        per_q[:, i, 9 + i] = 1.0
    return InputSource(name, np.asarray(param_cov, float), ref_nt=per_q @ jac, **kw)


@dataclass
class Contribution:
    name: str
    covariance: np.ndarray  # (P,P)
    field_rms_nt: float  # RMS over the grid of the calibrated field's vector error it causes (standard)
    method: str  # "exact (linear)" or "first order"
    jacobian: np.ndarray | None = None  # (P,Q), None for the fit's own noise
    source: InputSource | None = None
    grid_effect: np.ndarray | None = None  # a_grid (G,3,Q): its direct effect on the true field
    # (its parameters' variances (P,), the field's mean square error (nT^2), dof) of each part of it
    # estimated from few readings: the Welch-Satterthwaite sums (LinearBudget.effective_dof)
    dof_parts: list = field(default_factory=list)


@dataclass
class LinearBudget:
    layout: ParamLayout
    estimate: np.ndarray  # (P,) the calibration's flat parameters
    covariance: np.ndarray  # (P,P) all inputs together
    contributions: list[Contribution]
    grid_field_nt: np.ndarray  # (G,3)
    grid_temp_c: np.ndarray | None
    grid_h_nt: np.ndarray  # (G,3) raw readings the calibration maps to the grid fields
    field_jacobian: np.ndarray  # (G,3,P)
    field_covariance: np.ndarray  # (G,3,3)
    radius_nt: np.ndarray  # (G,) 95 % radius of the field's 3-D error per grid point
    first_order: bool = False  # some contribution is first order
    notes: list[str] = field(default_factory=list)

    @property
    def standard(self) -> dict[str, np.ndarray]:
        return self.layout.unflatten(np.sqrt(np.diag(self.covariance)))

    @property
    def field_rms_nt(self) -> float:
        """The combined standard uncertainty of the calibrated field: RMS over the grid of its error."""
        return float(np.sqrt(np.mean(np.trace(self.field_covariance, axis1=1, axis2=2))))

    def effective_dof(self) -> tuple[np.ndarray, float]:
        """(each flat parameter's effective degrees of freedom (P,), the calibrated field's): Welch-
        Satterthwaite (GUM G.4.1) over the parts of the budget estimated from few readings; inf where
        every input is known."""
        parts = [p for c in self.contributions for p in c.dof_parts]
        u2 = np.diag(self.covariance)
        per_param = np.array([effective_dof(u2[j], [(pv[j], dof) for pv, _, dof in parts])
                              for j in range(len(u2))])
        return per_param, effective_dof(self.field_rms_nt ** 2, [(ms, dof) for _, ms, dof in parts])


def _field_covariance(jac: np.ndarray, cov: np.ndarray) -> np.ndarray:
    return np.einsum("gip,pq,gjq->gij", jac, cov, jac, optimize=True)


def _direct_part(f_jac: np.ndarray, jac: np.ndarray, a_grid: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(G,3,3): what a source's direct effect adds to F J Sigma J^T F^T, its field error being
    (F J - a_grid) q: a Sigma a^T - F J Sigma a^T - (F J Sigma a^T)^T."""
    fj = np.einsum("gip,pq->giq", f_jac, jac)
    cross = np.einsum("giq,qr,gjr->gij", fj, cov, a_grid, optimize=True)
    return np.einsum("giq,qr,gjr->gij", a_grid, cov, a_grid, optimize=True) - cross - \
        np.swapaxes(cross, 1, 2)


def propagate_linear(ds: Dataset, cal: Calibration, sources: list[InputSource], grid, *,
                     weights: np.ndarray | None = None, statistical: bool = True, lin=None) -> LinearBudget:
    """The covariance of `cal`'s parameters from `sources` (and the fit's own noise), each source's share,
    and the calibrated field's error over `grid` = (fields (G,3) nT, temperatures (G,) or None).
    weights: the rows' weights in the fit (zeros for rows a robust fit left out)."""
    lin = lin or linearised(ds, cal, weights)
    grid_field, grid_temp = np.atleast_2d(np.asarray(grid[0], float)), grid[1]
    grid_temp = None if grid_temp is None else np.asarray(grid_temp, float)
    grid_h = raw_for(cal, grid_field, grid_temp)
    f_jac = field_jacobian(cal, grid_h, grid_temp)
    contributions = []
    if statistical:
        c = lin.statistical_covariance()
        rms = _rms(_field_covariance(f_jac, c))
        contributions.append(Contribution(STATISTICAL, c, rms,
                                          "exact (linear)" if lin.exact_in_reference else "first order",
                                          dof_parts=[(np.diag(c), rms**2, _residual_dof(lin, cal))]))
    direct = np.zeros((len(grid_h), 3, 3))
    for source in sources:
        a_ref, a_temp = source.sensitivities(ds)
        sigma_q = np.atleast_2d(np.asarray(source.covariance, float))
        jac = np.zeros((lin.layout.size, sigma_q.shape[0]))
        exact = True
        if a_ref is not None:
            jac += lin.ref_jacobian(a_ref)
            exact = lin.exact_in_reference
        if a_temp is not None:
            jac += lin.temp_jacobian(a_temp)
            exact = False
        c = jac @ sigma_q @ jac.T
        field_cov = _field_covariance(f_jac, c)
        a_grid = source.grid_effect(grid_h, grid_temp)
        if a_grid is not None:
            extra = _direct_part(f_jac, jac, a_grid, sigma_q)
            field_cov, direct = field_cov + extra, direct + extra
        contributions.append(Contribution(source.name, c, _rms(field_cov),
                                          "exact (linear)" if exact else "first order", jac, source, a_grid,
                                          _estimated_parts(source, jac, f_jac, a_grid)))
    total = sum((c.covariance for c in contributions), np.zeros((lin.layout.size,) * 2))
    f_cov = _field_covariance(f_jac, total) + direct
    return LinearBudget(lin.layout, lin.layout.flatten(cal.params), total, contributions, grid_field,
                        grid_temp, grid_h, f_jac, f_cov, gaussian_radius(f_cov),
                        any(c.method == "first order" for c in contributions))


def _residual_dof(lin, cal: Calibration) -> float:
    """The fit's residual degrees of freedom: rows used less the parameters (per axis for a vector model,
    whose axes are fitted apart)."""
    size = lin.layout.size / (3 if registry.spec(cal.model).vector else 1)
    return max(float(np.count_nonzero(lin.w)) - size, 1.0)


def _estimated_parts(source: InputSource, jac: np.ndarray, f_jac: np.ndarray, a_grid) -> list:
    """dof_parts of a source: per Estimated, its parameters' variances and the field's mean square."""
    out = []
    for part in source.estimated:
        index, variance = np.asarray(part.index, int), np.asarray(part.variance, float)
        if not np.any(variance > 0):
            continue
        jg = jac[:, index]
        fj = np.einsum("gip,pk->gik", f_jac, jg)
        if a_grid is not None:
            fj = fj - a_grid[:, :, index]
        out.append(((jg**2) @ variance, float(np.mean(np.einsum("gik,k->g", fj**2, variance))), part.dof))
    return out


def _rms(field_cov: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.trace(field_cov, axis1=1, axis2=2))))


def cross_covariance(a: LinearBudget, b: LinearBudget) -> np.ndarray:
    """(Pa,Pb): cov(theta_a, theta_b) from the input quantities the two calibrations share (sources with
    the same `shared` name): sum of J_a Sigma_q J_b^T. Their statistical parts are independent."""
    out = np.zeros((a.layout.size, b.layout.size))
    theirs = {c.source.shared: c for c in b.contributions if c.source is not None and c.source.shared}
    for mine in a.contributions:
        if mine.source is None or not mine.source.shared or mine.source.shared not in theirs:
            continue
        other = theirs[mine.source.shared]
        cov = np.atleast_2d(mine.source.covariance)
        if other.jacobian.shape[1] != cov.shape[0]:
            raise DataError(f"shared input {mine.source.shared!r}: {cov.shape[0]} quantities in one "
                            f"calibration, {other.jacobian.shape[1]} in the other")
        out += mine.jacobian @ cov @ other.jacobian.T
    return out
