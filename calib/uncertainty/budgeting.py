"""A calibration's uncertainty budget: exact linear propagation where the model is linear, adaptive Monte
Carlo (GUM S1) where it is needed.

    b = budget(ds, cal, sources, grid, rng=rng)      # calib.uncertainty.montecarlo.Budget
    cal.uncertainty = b.as_dict()                    # the calibration file's `uncertainty:` section
    cross_covariance_of(b_a, b_b)                    # two DUTs sharing the campaign's coil matrix

1. Law of propagation (calib/uncertainty/propagation.py): every source's covariance J Sigma_q J^T, the fit's
   own sigma^2 G^-1, their sum, each one's RMS field error over the grid. Exact for T24 / T36 and sources
   that change the references; first order for P12, the scalar fit and temperature changes (said so).
2. Monte Carlo where that is not the whole answer (`needs_monte_carlo`, monte_carlo="auto"): where a
   first-order map does not hold to within half the numerical tolerance (the scalar fit, checked by
   VALIDATION_DRAWS exact refits, `validate_scalar`; temperature changes on T24 / T36, checked the same
   way, calib/uncertainty/lawcheck.py), or where non-normal inputs (a rectangular tolerance) move a coverage
   interval away from +-1.96 u by more than that (their kurtosis, calib/uncertainty/lawcheck.py). The draws:
   every draw adds the linear sources' J q to the refitted part (T24 / T36 refitted exactly for their
   temperature sources, the scalar fit refitted or through its validated map), so the draws are of all
   inputs together; the number of draws is chosen by the adaptive procedure of GUM S1 7.9
   (calib/uncertainty/adaptive.py). Parameters' u and coverage intervals, and the calibrated field's error at
   each grid point, come from the draws; the covariance from the draws when refits were made, else from the
   law of propagation (exact whatever the inputs' distributions). monte_carlo="always" draws whatever
   the checks say.
3. Without Monte Carlo: u and the covariance from the law of propagation, intervals +-1.96 u, the field's
   95 % radius at each point from its 3x3 covariance; the method says which checks held.

The field error is judged at every grid point: `vector_error_nt` holds the 95 % radius per point, its
maximum and the 95th percentile over the points; `expanded_vector_error_nt` is the maximum, so the worst
point is covered. A source may also move the true field at the grid points directly (a model error the
calibration cannot follow, InputSource.field_nt): its error there is (F J - a_grid) q.
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.stats.student import coverage_factor, widening
from calib.uncertainty.adaptive import MAX_DRAWS, adaptive_monte_carlo, numerical_tolerance, quantiles
from calib.uncertainty.correction import Corrected, DataCorrection
from calib.uncertainty.lawcheck import (
    VALIDATION_DRAWS,
    covariance_root,
    normal_interval_holds,
    unit_draws,
    validate_temperature,
)
from calib.uncertainty.linearise import ScalarGaussNewton, linearised
from calib.uncertainty.mcrefit import ScalarRefit, draw_chunks, refit_for
from calib.uncertainty.montecarlo import Budget
from calib.uncertainty.propagation import (
    STATISTICAL,
    InputSource,
    LinearBudget,
    cross_covariance,
    propagate_linear,
)
from calib.uncertainty.rowgroups import RowGroups

Z_975 = 1.959963984540054
NDIG = 1  # significant digits the adaptive Monte Carlo settles (GUM S1 7.9.2: usually 1 or 2)
# draws per batch: J = 100 / (1 - p) for p = 0.95. S1 7.9.4 takes max(J, 10^4); the stopping rule is the
# same, smaller batches only let it stop nearer the number of draws the tolerance needs (stated in `method`)
BATCH_DRAWS = 2000
SCALAR_BATCH, SCALAR_MAX_DRAWS = 500, 2000  # a scalar Monte Carlo refitting every draw stops there
VALIDATION_SHARE = 0.5  # of the numerical tolerance: how far they may stray from the map
# rows a scalar fit's Monte Carlo refits at most: beyond, an evenly spaced subset (_thinned_scalar)
SCALAR_MC_ROWS = 2048


def needs_monte_carlo(ds: Dataset, cal: Calibration, lin, linear: LinearBudget, sources: list[InputSource],
                      rng: np.random.Generator, *, statistical: bool, ndig: int,
                      notes: list[str]) -> tuple[list[str], bool | None, int]:
    """(why the law of propagation alone is not the whole answer (empty: it is), whether the scalar fit
    needs refits (None: not checked), refits that failed in the checks); what each check found is added
    to `notes`."""
    why, scalar_refits, failed = [], None, 0
    if isinstance(lin, ScalarGaussNewton):
        holds, found, failed = validate_scalar(lin, linear, sources, rng, statistical=statistical, ndig=ndig)
        notes.append(found)
        scalar_refits = not holds
        if not holds:
            why.append("the scalar fit is not linear in its data here")
    elif cal.model in ("t24", "t36") and any(s.temp_c is not None for s in sources):
        holds, found, bad = validate_temperature(lin, linear, sources, rng, ndig=ndig)
        notes.append(found)
        failed += bad
        if not holds:
            why.append("temperature changes move the regressors beyond first order")
    holds, found = normal_interval_holds(linear, ndig)
    if found != "every input normal":
        notes.append(found)
    if not holds:
        why.append("inputs that are not normal move the coverage intervals")
    return why, scalar_refits, failed



_unit = unit_draws


class _Draws:
    """Makes batches of draws of every input: (parameter changes (m,P), field error lengths (m,G), failed).

    Every draw is the sum of J q over the sources handled by a linear map and of the refitted change for
    the others: T24 / T36 refitted exactly for their temperature sources (calib/uncertainty/mcrefit.py); the
    scalar fit through its first-order map when `validate_scalar` showed refits agree with it, else
    refitted."""

    def __init__(self, ds: Dataset, cal: Calibration, lin, linear: LinearBudget, sources: list[InputSource],
                 statistical: bool, scalar_refits: bool, refit_temperature: bool = True):
        self.cal, self.lin, self.linear = cal, lin, linear
        self.scalar = isinstance(lin, ScalarGaussNewton)
        self.scalar_refits = self.scalar and scalar_refits
        self.linear_parts = []  # (J (P,Q), root of Sigma_q, distribution, a_grid): J q added to every draw
        self.data_parts = []  # (root, distribution, a_ref, a_temp): changes the data of a refit
        by_name = {c.name: c for c in linear.contributions}
        if statistical and not self.scalar_refits:
            own = covariance_root(by_name[STATISTICAL].covariance)
            self.linear_parts.append((np.eye(linear.layout.size), own, "normal", None))
        for source in sources:
            a_ref, a_temp = source.sensitivities(ds)
            root = covariance_root(source.covariance)
            a_grid = by_name[source.name].grid_effect
            if a_grid is not None:  # a model error: its data and its direct effect through one linear map
                self.linear_parts.append((by_name[source.name].jacobian, root, source.distribution, a_grid))
            elif self.scalar_refits:
                self.data_parts.append((root, source.distribution, _by_quantity(a_ref, len(ds)), a_temp))
            elif a_temp is not None and cal.model in ("t24", "t36") and refit_temperature:
                if a_ref is not None:
                    self.linear_parts.append((lin.ref_jacobian(a_ref), root, source.distribution, None))
                self.data_parts.append((root, source.distribution, None, a_temp))
            else:
                self.linear_parts.append((by_name[source.name].jacobian, root, source.distribution, None))
        temps = [a for (_, _, _, a) in self.data_parts if a is not None]
        self.refit = None
        if self.scalar_refits or temps:
            self.refit = refit_for(lin, np.column_stack(temps) if temps else None)
        self.noise_nt = np.sqrt(lin.sigma2) if self.scalar_refits and statistical else None

    def __call__(self, rng: np.random.Generator, m: int):
        change = np.zeros((m, self.linear.layout.size))
        direct = None  # (m,G,3): the draws' direct effects on the true field at the grid points
        for jac, root, dist, a_grid in self.linear_parts:
            q = _unit(rng, dist, (m, root.shape[1])) @ root.T
            change += q @ jac.T
            if a_grid is not None:
                moved = np.einsum("giq,mq->mgi", a_grid, q)
                direct = moved if direct is None else direct + moved
        failed = np.zeros(m, bool)
        if self.refit is not None:
            qs = [(_unit(rng, dist, (m, root.shape[1])) @ root.T, a_ref, a_temp)
                  for root, dist, a_ref, a_temp in self.data_parts]
            if self.scalar_refits:  # in chunks: every draw holds a copy of the data
                for rows in draw_chunks(m, len(self.lin.ds)):
                    dh, dref, dt = _scalar_data(rng, [(q[rows], a, b) for q, a, b in qs],
                                                rows.stop - rows.start, len(self.lin.ds), self.noise_nt)
                    change[rows], failed[rows] = self.refit(dh, dref, dt)
            else:
                moved, failed = self.refit(np.column_stack([q for q, _, _ in qs]))
                change += moved
        error = self._field_error(change)
        if direct is not None:
            error -= direct
        return change, np.sqrt(np.einsum("mgi,mgi->mg", error, error)), failed

    def _field_error(self, change: np.ndarray) -> np.ndarray:
        """(m,G,3): exact for the scalar model (bilinear in its parameters), F dtheta for the others (exact
        for T24 and T36, linear in their parameters; first order for P12)."""
        lb = self.linear
        if not self.scalar:
            g = len(lb.grid_h_nt)
            return (change @ lb.field_jacobian.reshape(3 * g, -1).T).reshape(len(change), g, 3)
        drawn = lb.layout.unflatten(lb.estimate + change)
        h, temp = lb.grid_h_nt, lb.grid_temp_c
        t = np.zeros(len(h)) if temp is None or self.cal.temp_ref_c is None else temp - self.cal.temp_ref_c
        v = h[None] - drawn["c_nt"][:, None, :]
        with np.errstate(over="ignore", invalid="ignore"):  # a diverged refit's draw: counted failed
            if "KA_per_c" in drawn:
                v = v - t[None, :, None] * drawn["kc_nt_per_c"][:, None, :]
            field = v @ drawn["A"].transpose(0, 2, 1)
            if "KA_per_c" in drawn:
                field = field + t[None, :, None] * (v @ drawn["KA_per_c"].transpose(0, 2, 1))
            return field - self.cal.apply(h, temp)[None]


def _by_quantity(a_ref, n: int):
    """A dense a_ref (N,3,Q) as its (Q,3N) transpose, made once for every chunk of draws (None and the
    compact form as they are)."""
    if a_ref is None or isinstance(a_ref, RowGroups):
        return a_ref
    return np.ascontiguousarray(np.reshape(a_ref, (3 * n, -1)).T)


def _scalar_data(rng, qs, m: int, n: int, noise_nt):
    """(dh (m,N,3) or None, dref (m,N,3) or None, dt (m,N) or None) of m drawn datasets; qs: (q (m,Q),
    a_ref as `_by_quantity` gives it, a_temp (N,Q)) per source."""
    dh = None if noise_nt is None else rng.standard_normal((m, n, 3)) * noise_nt
    dref = _total(a.rows_times(q) if isinstance(a, RowGroups) else (q @ a).reshape(m, n, 3)
                  for q, a, _ in qs if a is not None)
    dt = _total(q @ a.T for q, _, a in qs if a is not None)
    return dh, dref, dt


def validate_scalar(lin: ScalarGaussNewton, linear: LinearBudget, sources: list[InputSource], rng, *,
                    statistical: bool, ndig: int, draws: int = VALIDATION_DRAWS) -> tuple[bool, str, int]:
    """(the first-order map holds, what was found, refits failed): `draws` datasets drawn from every input
    are refitted exactly and compared draw by draw with the first-order map. When no parameter moves off
    it by more than VALIDATION_SHARE (half) of its numerical tolerance delta (GUM S1 7.9.2), the quantiles
    and u of draws made through the map are those of refitted draws to within delta / 2 (an order
    statistic moves no more than the draws do, and the draws that set a 95 % interval's ends lie about
    2 sd out, where 100 draws already reach): the same allowance the adaptive rule gives its own scatter
    (2 s <= delta), so the Monte Carlo may use the map. That bound is loose where the map's error is of
    second order (it grows as the square of a draw, and the largest of 100 draws sits 2.5 sd out): the
    draws being paired, the map's error also gives the shift of every parameter's 95 % interval ends
    directly, |mean d| + 1.96 |du| (du = (var d + 2 cov(map, d)) / 2u) plus twice its sampling error, and
    the map holds when that is within the same share of delta (the comparison of GUM S1 8.2, made on the
    parameters). Else every draw is refitted (slower, said so)."""
    by_name = {c.name: c for c in linear.contributions}
    qs, linear_change = [], np.zeros((draws, linear.layout.size))
    for source in sources:
        a_ref, a_temp = source.sensitivities(lin.ds)
        q = _unit(rng, source.distribution, (draws, np.atleast_2d(source.covariance).shape[0])) @ \
            covariance_root(source.covariance).T
        qs.append((q, _by_quantity(a_ref, len(lin.ds)), a_temp))
        linear_change += q @ by_name[source.name].jacobian.T
    noise = np.sqrt(lin.sigma2) if statistical else None
    if noise is None and all(a_ref is None and a_temp is None for _, a_ref, a_temp in qs):
        return True, "no input to draw", 0
    refit, n = refit_for(lin, None), len(lin.ds)
    refitted, failed = np.empty_like(linear_change), np.zeros(draws, bool)
    for rows in draw_chunks(draws, n):  # the drawn data a chunk at a time (the same draws as at once)
        dh, dref, dt = _scalar_data(rng, [(q[rows], a, b) for q, a, b in qs], rows.stop - rows.start, n,
                                    noise)
        if dh is not None:
            linear_change[rows] += lin.reading_change(dh)
        refitted[rows], failed[rows] = refit(dh, dref, dt)
    d, mapped = refitted[~failed] - linear_change[~failed], linear_change[~failed]
    off = np.max(np.abs(d), axis=0, initial=0.0)
    u = np.sqrt(np.diag(linear.covariance))
    delta = numerical_tolerance(u, ndig)
    ratio = _share(off, delta)
    paired = np.inf
    if len(d) > 2:
        du = (d.var(axis=0, ddof=1) + 2 * np.mean((mapped - mapped.mean(0)) * (d - d.mean(0)), axis=0)) / \
            (2 * np.where(u > 0, u, 1.0))
        shift = np.abs(d.mean(axis=0)) + Z_975 * np.abs(du) + 2 * d.std(axis=0, ddof=1) / np.sqrt(len(d))
        paired = _share(shift, delta)
    holds = min(ratio, paired) <= VALIDATION_SHARE and not failed.any()
    return holds, (f"{draws} refitted draws stay within {ratio:.2g} of the numerical tolerance of the "
                   f"first-order map and move its 95 % intervals by {paired:.2g} of it "
                   f"({'it holds' if holds else 'refitting every draw'})"), int(failed.sum())


def _share(values: np.ndarray, delta: np.ndarray) -> float:
    """The largest value / delta over the parameters with a tolerance."""
    return float(np.max(np.where(delta > 0, values / np.where(delta > 0, delta, 1.0), 0.0), initial=0.0))


def _total(parts):
    """The sum of the arrays given, None when none is."""
    out = None
    for part in parts:
        out = part if out is None else out + part
    return out


def budget(ds: Dataset, cal: Calibration, sources: list[InputSource], grid, *, rng: np.random.Generator,
           weights: np.ndarray | None = None, statistical: bool = True, monte_carlo: str = "auto",
           ndig: int = NDIG, batch_draws: int | None = BATCH_DRAWS, max_draws: int = MAX_DRAWS,
           scalar_refits: bool | None = None, noise_nt: np.ndarray | None = None,
           correction: DataCorrection | None = None) -> Budget:
    """The uncertainty budget of `cal` (fitted to `ds` with row `weights`) over `sources` and the fit's own
    noise (`statistical`), the field error judged over `grid` = (fields (G,3) nT, temperatures (G,) or
    None). monte_carlo: "auto" (where needed), "always" or "never" (the law of propagation alone).
    scalar_refits: refit every draw of a scalar calibration (True), or only when `validate_scalar` finds
    its first-order map does not hold (None). noise_nt (3,): the readings' noise per axis known apart from
    the residual (calib.uncertainty.linearise.linearised). correction: one the data were given before the fit,
    estimated from them (calib/uncertainty/correction.py)."""
    lin = linearised(ds, cal, weights, noise_nt)
    lin = lin if correction is None else Corrected(lin, correction)
    linear = propagate_linear(ds, cal, sources, grid, statistical=statistical, lin=lin)
    notes = [f"{c.name}: first order" for c in linear.contributions if c.method == "first order"]
    whole = (ds, lin, linear, sources)
    refitting = whole  # what the scalar fit's refits (its check and its draws) are made on
    thinned = None
    if isinstance(lin, ScalarGaussNewton) and len(ds) > SCALAR_MC_ROWS and monte_carlo != "never":
        thinned = _thinned_scalar(ds, cal, weights, lin, sources, grid, statistical)
    if thinned is not None:
        refitting = thinned
        notes.append(f"the scalar fit's refits are made on {len(thinned[0])} of its {len(ds)} rows, evenly "
                     "spaced, their noise scaled so that its spread in the parameters is the whole data's")
    r_ds, r_lin, r_linear, r_sources = refitting
    checked_failed, refit_temperature = 0, True
    if monte_carlo == "auto":
        why, checked, checked_failed = needs_monte_carlo(r_ds, cal, r_lin, r_linear, r_sources, rng,
                                                         statistical=statistical, ndig=ndig, notes=notes)
        scalar_refits = checked if scalar_refits is None else scalar_refits
        refit_temperature = any("temperature" in w for w in why)
    else:
        why = ["asked for"] if monte_carlo == "always" else []
    if why:
        if isinstance(lin, ScalarGaussNewton) and scalar_refits is None:  # checked on the refits' rows
            holds, found, bad = validate_scalar(r_lin, r_linear, r_sources, rng, statistical=statistical,
                                                ndig=ndig)
            notes.append(found)
            scalar_refits, checked_failed = not holds, checked_failed + bad
        mc_ds, mc_lin, mc_linear, mc_sources = refitting if scalar_refits else whole  # maps: the whole's
        figures = _monte_carlo(mc_ds, cal, mc_lin, mc_linear, mc_sources, rng, statistical=statistical,
                               ndig=ndig, batch_draws=batch_draws, max_draws=max_draws, why=why, notes=notes,
                               scalar_refits=scalar_refits, refit_temperature=refit_temperature,
                               checked_failed=checked_failed)
    else:
        u = np.sqrt(np.diag(linear.covariance))
        checks = " (the checks above held)" if monte_carlo == "auto" and (linear.first_order or any(
            c.source is not None and c.source.distribution != "normal" for c in linear.contributions)) else ""
        method = "law of propagation (GUM), " + ("first order" if linear.first_order
                                                 else "exact: a linear model") + checks
        figures = {"u": u, "low": -Z_975 * u, "high": Z_975 * u, "radius": linear.radius_nt,
                   "rms": linear.field_rms_nt, "covariance": linear.covariance, "method": method, "mc": None}
    layout, mc = linear.layout, figures["mc"]
    dof, dof_field = linear.effective_dof()  # k and the 95 % intervals from them (calib/stats/student.py)
    k, widen = np.array([coverage_factor(v) for v in dof]), np.array([widening(v) for v in dof])
    k_field = coverage_factor(dof_field)
    if np.any(np.isfinite(dof)) or np.isfinite(dof_field):
        said = "infinite" if not np.isfinite(dof_field) else f"{dof_field:.3g}"
        figures["method"] += (f"; k from effective degrees of freedom (Welch-Satterthwaite, GUM G.4): the "
                              f"field's {said}, k = {k_field:.3g}")
    radius = np.asarray(figures["radius"], float) * widening(dof_field)
    standard = layout.unflatten(figures["u"])
    low, high = (layout.unflatten(linear.estimate + widen * figures[name]) for name in ("low", "high"))
    return Budget(
        coverage_factor=k_field, standard=standard,
        expanded=layout.unflatten(k * figures["u"]),
        coverage_factors=layout.unflatten(k), effective_dof=layout.unflatten(dof), field_dof=dof_field,
        contributions=[{"source": c.name, "contribution_nt": c.field_rms_nt, "method": c.method,
                        **({"note": c.source.origin} if c.source is not None and c.source.origin else {})}
                       for c in linear.contributions],
        combined_standard_nt=figures["rms"], expanded_vector_error_nt=float(np.max(radius)),
        draws=0 if mc is None else mc["draws"], notes=notes, method=figures["method"],
        interval={k: (low[k], high[k]) for k in layout.names},
        covariance=figures["covariance"], parameter_labels=layout.labels(),
        vector_error_nt={"per_point": radius.tolist(), "max": float(np.max(radius)),
                         "percentile_95": float(quantiles(radius[:, None], [0.95])[0, 0]),
                         "grid_field_nt": linear.grid_field_nt.tolist(),
                         "grid_temp_c": None if linear.grid_temp_c is None else linear.grid_temp_c.tolist()},
        failed_draws=checked_failed if mc is None else mc["failed"],
        stated=True if mc is None else mc["stated"],
        monte_carlo=mc, linear=linear)


Problem = tuple[Dataset, ScalarGaussNewton, LinearBudget, list[InputSource]]


def _thinned_scalar(ds: Dataset, cal: Calibration, weights, lin: ScalarGaussNewton, sources, grid,
                    statistical: bool) -> Problem | None:
    """The scalar fit's problem on SCALAR_MC_ROWS rows evenly spaced through the data (in the order taken,
    so every point and temperature keeps its share): (dataset, linearisation, linear budget, sources).
    Its noise variance is the whole data's times M/N: the fit of M rows then spreads as the fit of N does
    (its normal matrix is M/N of theirs). Its solution is its own least squares, which draws move from;
    None where that solution is not found (the whole data are refitted then)."""
    rows = np.unique(np.linspace(0, len(ds) - 1, SCALAR_MC_ROWS).round().astype(int))
    thin_ds = ds.subset(rows)
    thin = ScalarGaussNewton(thin_ds, cal, None if weights is None else np.asarray(weights)[rows])
    thin.sigma2 = lin.sigma2 * len(rows) / len(ds)
    theta = ScalarRefit(thin).own_solution()
    if theta is None:
        return None
    thin.theta = theta
    thin_sources = [source.take(rows) for source in sources]
    thin_linear = propagate_linear(thin_ds, cal, thin_sources, grid, statistical=statistical, lin=thin)
    return thin_ds, thin, thin_linear, thin_sources


def _monte_carlo(ds, cal, lin, linear, sources, rng, *, statistical, ndig, batch_draws, max_draws, why,
                 notes, scalar_refits, refit_temperature=True, checked_failed=0) -> dict:
    """The figures of the adaptive Monte Carlo (u, interval offsets, radius per grid point, ...); for a
    scalar fit, whether its draws are refitted is decided already (budget)."""
    refits = bool(scalar_refits)
    draws = _Draws(ds, cal, lin, linear, sources, statistical, refits, refit_temperature)
    if draws.scalar_refits:  # each draw a scalar refit (~1 ms): limited; the result says if it converged
        batch_draws = min(batch_draws or SCALAR_BATCH, SCALAR_BATCH)
        max_draws = min(max_draws, SCALAR_MAX_DRAWS)
    result = adaptive_monte_carlo(draws, rng, ndig=ndig, batch_size=batch_draws, max_draws=max_draws)
    refitted = draws.refit is not None  # else every draw is a linear map: its covariance is exact
    if not result.stated:
        notes.append(result.message)
    failed = result.failed + checked_failed
    return {"u": result.u if refitted else np.sqrt(np.diag(linear.covariance)),
            "low": result.low, "high": result.high, "radius": result.length_quantile,
            "rms": float(np.sqrt(np.mean(result.length_rms**2))),
            "covariance": (np.cov(result.values, rowvar=False) if refitted and len(result.values) > 1
                           else linear.covariance),
            "method": f"Monte Carlo (GUM S1, adaptive), {result.message}; because {'; '.join(why)}",
            "mc": {"draws": result.draws, "failed": failed, "batches": result.batches,
                   "batch_size": result.batch_size, "converged": result.converged, "ndig": ndig,
                   "stated": result.stated, "refits": "every draw" if refitted else "none (linear maps)"}}


def cross_covariance_of(a: Budget, b: Budget) -> np.ndarray:
    """(Pa,Pb) between two budgets' parameters through the input quantities they share (first order for
    the models that are not linear); see calib.uncertainty.propagation.cross_covariance."""
    return cross_covariance(a.linear, b.linear)
