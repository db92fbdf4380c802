"""The uncertainty a calibration states, measured (issue: an uncertainty a metrologist would sign).

1. coverage: independent simulated worlds (bench/coverage_worlds.py: >= 20 stations x 5 DUTs, every
   systematic error drawn from a distribution wider than the one the station states), each commissioned
   and run with the demo plan (T24); per DUT the calibration file as the rig wrote it. Reported: the share
   of the true T24 parameters within their expanded uncertainty (U = k u, k from each one's effective
   degrees of freedom) per group, and of the true vector error at validation points (other directions
   and magnitudes, temperatures between the plan's, either thermal direction) within the 95 % radius the
   file gives there (calib/uncertainty/fielderror.py: its covariance and model error), over all points and
   over each DUT's worst 5 % (the points with the largest stated radius: where the calibration is least
   certain). Goal 90-98 %. The true parameters: the model's best description of the DUT over the fields and
   temperatures its data were taken at (`conditions`). --model p12 fits and judges P12 instead (its k,
   angles and offsets; its field error at the same points, where its model error is most of it);
   --model scalar the |B|-only fit (its A, c and their temperature terms against the best scalar fit; at
   the validation points its error of |B|, what a scalar fit answers for, against the 95 % interval of
   |B|'s error its file states, rig apply's u_norm: a rotation of the output, which |B| cannot see, is not
   judged).
   Beside the coverage, the vector error's two parts at the validation points, each against what the file
   states of it (RMS): the parameters' (the calibration against the model's best description of the DUT)
   and the model's with the thermal state (that description against the true field). --temperatures runs
   the plan with other temperature steps (the validation temperatures between them).
2. timing: every budget (T24, P12, scalar) of a 64-DUT campaign, and the demo's wall time on 64 DUTs
   against 2 (bench/uncertainty_timing.py).
3. certificates: the demo's DUTs (rig certificate).

    .venv/bin/python bench/uncertainty.py coverage [--worlds 20] [--seed 24] [--wider 1.25] [--out DIR]
                                                   [--jobs 2] [--table] [--field-order listed]
                                                   [--model t24|p12|scalar] [--again]
                                                   [--temperatures -20,0,25,60]
    .venv/bin/python bench/uncertainty.py timing [--before COMMIT] | certificates
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import calib  # noqa: E402
from bench.coverage_worlds import BASE, TABLE_FIELDS, WIDER, random_world, table_world  # noqa: E402
from bench.reference_chain import PLACES_MM, prepared, run, validation_grid  # noqa: E402
from calib.calibration import standard_uncertainty  # noqa: E402
from calib.dataset import Dataset  # noqa: E402
from calib.io import calfile  # noqa: E402
from calib.stats.directions import beyond_taken  # noqa: E402
from calib.uncertainty.fielderror import expanded_at, expanded_norm_at, field_covariance, hysteresis_state_nt  # noqa: E402
from rig.config import load_station  # noqa: E402
from rig.core.paths import calibration_file  # noqa: E402
from rig.devices.simulated.world import dut_truths  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "configs" / "plans" / "demo.yaml"
DEMO_STEPS_C = yaml.safe_load(DEMO.read_text())["temperatures"]["steps"]
GROUPS = {"S": "S", "K": "K", "b": "b_nt", "kb": "kb_nt_per_c"}
# each model's parameter groups (report name: the calibration file's key)
MODEL_GROUPS = {"t24": GROUPS, "p12": {"k": "k", "angles": "angles_deg", "h0": "h0_nt"},
                "scalar": {"A": "A", "c": "c_nt", "KA": "KA_per_c", "kc": "kc_nt_per_c"}}
WORST_SHARE = 0.05


def plan_t24(folder: Path, table: bool = False, field_order: str | None = None, model: str = "t24",
             temperatures: list[float] | None = None) -> Path:
    data = yaml.safe_load(DEMO.read_text())
    if temperatures is not None:
        data["temperatures"]["steps"] = list(temperatures)
    data["fit"] = {"models": [model], "robust": False}
    if field_order is not None:
        data["field_order"] = field_order
    if table:
        data["fields"] = TABLE_FIELDS
    data.pop("station", None)
    path = folder / "plan.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def best_t24(truth, temp_ref_c: float, fields=None, temps=None) -> dict:
    """The T24 parameters that describe the DUT best over the calibration's conditions (`best_fit`): what
    its calibration measures. The truth's own S, K, b, kb when it has no term beyond T24."""
    if truth.deviations is None:
        return {"S": truth.S, "K": truth.K, "b_nt": truth.b_nt, "kb_nt_per_c": truth.kb_nt_per_c}
    cal = best_fit(truth, "t24", temp_ref_c, fields, temps)
    return {k: np.asarray(v, float) for k, v in cal.params.items()}


def best_fit(truth, model: str, temp_ref_c: float, fields=None, temps=None, **options):
    """The calibration of `model` that describes the DUT best over the calibration's conditions, fitted to
    its noiseless readings there: the fields and temperatures (N,3), (N,) of its data (`conditions`), or
    the demo's fields (or `fields`) at each of its temperatures."""
    if temps is None:
        plan = yaml.safe_load(DEMO.read_text())
        if fields is None:
            dirs = np.asarray(plan["fields"]["directions"], float)
            fields = plan["fields"]["magnitude_nt"] * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        steps = np.asarray(plan["temperatures"]["steps"], float)
        fields, temps = np.tile(fields, (len(steps), 1)), np.repeat(steps, len(fields))
    h = np.array([truth.raw_from_field(b, tc) for b, tc in zip(fields, temps, strict=True)])
    return calib.fit(Dataset(h_nt=h, temp_c=temps, ref_nt=fields), model, temp_ref_c=temp_ref_c, **options)


def conditions(session: Path, duts) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per DUT, the fields and temperatures its calibration data were taken at, as its fit saw them (the
    run's references and the DUT's temperatures): a model that cannot follow the DUT (P12 has no rotation
    or temperature terms, the scalar fit no rotation) describes it best over the very fields it was shown,
    and a table's poses sit a degree or two from their drawing. Their own errors move this truth by second
    order only (a field error of tens of nT times the model's misfit over |B|)."""
    from rig.analysis.sessionfit import SessionFitter
    from rig.session.reader import SessionReader, read_dataset

    with SessionReader(session) as reader:
        fitter = SessionFitter.of(reader)  # the session's reference chain, read once for its DUTs
    out = {}
    for dut in duts:
        ds = fitter.prepare(read_dataset(session, dut)).ds
        out[dut] = (ds.ref_nt, ds.temp_c)
    return out


def one_world(args) -> dict:
    """Build, commission and run one world; the coverage figures of its DUTs (none, and why, when the
    world could not be run)."""
    try:
        return _one_world(*args)
    except Exception as exc:  # noqa: BLE001 - one world that cannot run is reported, the others count
        return {"index": args[1], "rows": [], "error": f"{type(exc).__name__}: {exc}"}


def _one_world(seed: int, index: int, out: str, wider: float, table: bool = False,
               field_order: str | None = None, model: str = "t24", again: bool = False,
               temperatures: list[float] | None = None) -> dict:
    rng = np.random.default_rng([seed, index])
    folder = Path(out) / f"world{index:02d}"
    folder.mkdir(parents=True, exist_ok=True)
    reference = BASE.parent / "sim-reference-cal.yaml"
    world = random_world(rng, index, reference, wider)
    if table:  # the table is commissioned at home alone (its axes): no places, no loops
        world = table_world(world, rng)
    if again:  # the world drawn as before (the same rng), its station and session those already there
        station, session = folder / f"{world['name']}.yaml", folder / "train.session"
    else:
        station = prepared(world, BASE.parent, folder, places=() if table else PLACES_MM)
        session = run(station, plan_t24(folder, table, field_order, model, temperatures), folder)
    truths = dut_truths(load_station(station))
    site = world["sim"].get("site_field_nt")
    out_rows = []
    shown_to = None  # the data's conditions, read when a calibration is there to judge
    for dut, truth in truths.items():
        path = calibration_file(session, dut, model)
        if not path.exists():  # the fit refused (the session's events say why): counted apart
            said = "the session was run for another model" if again else "its fit failed"
            out_rows.append({"world": index, "dut": dut, "unstated": f"no {path.name}: {said}"})
            continue
        cal = calfile.load(path)
        if cal.uncertainty is None:  # the budget refused to state one (its warning says why): counted apart
            said = (cal.stats.get("warnings") or ["?"])[-1]
            out_rows.append({"world": index, "dut": dut, "unstated": said})
            continue
        expanded = {k: np.asarray(v, float) for k, v in cal.uncertainty["expanded"].items()}
        options = {} if model != "scalar" else {
            "temperature_terms": "KA_per_c" in cal.params, "field_norm_nt": cal.stats.get("field_norm_nt"),
            "balance_orientations": cal.stats.get("balance_orientations")}
        shown_to = shown_to or conditions(session, truths)
        shown = shown_to[dut]
        if model == "t24":
            true = best_t24(truth, cal.temp_ref_c, *shown)
        else:
            best = best_fit(truth, model, cal.temp_ref_c, *shown, **options)
            true = {k: np.asarray(v, float) for k, v in best.params.items()}
        groups = {g: k for g, k in MODEL_GROUPS[model].items() if k in cal.params}
        inside = {g: (np.abs(cal.params[k] - true[k]) <= expanded[k]).ravel().tolist()
                  for g, k in groups.items()}
        u = {k: np.maximum(standard_uncertainty(cal.uncertainty, k), 1e-300) for k in groups.values()}
        z = {g: (np.abs(cal.params[k] - true[k]) / u[k]).ravel().tolist() for g, k in groups.items()}
        fields, temps = validation_grid(np.array(temperatures or DEMO_STEPS_C, float))
        if table:  # a table's calibration knows one magnitude, the site field's: it is judged there
            fields = fields / np.linalg.norm(fields, axis=1, keepdims=True) * np.linalg.norm(site)
        hyst = np.zeros(3) if truth.deviations is None else truth.deviations.hysteresis_offset_nt
        state = rng.choice([-1.0, 1.0], len(fields))
        h = np.array([truth.raw_from_field(f, t, s * hyst)
                      for f, t, s in zip(fields, temps, state, strict=True)])
        error, radius = _judged(cal, h, temps, fields)
        described = dataclasses.replace(cal, params={k: np.asarray(v, float) for k, v in true.items()})
        parts = None if model == "scalar" else _parts(cal, described, h, temps, fields)
        taken = cal.stats.get("field_directions")  # rig apply's warning: beyond the directions taken
        beyond = beyond_taken(taken, cal.apply(h, temps))[0] if taken else np.zeros(len(error), bool)
        worst = np.argsort(radius)[-max(1, int(round(WORST_SHARE * len(error)))):]
        out_rows.append({"world": index, "dut": dut, "inside": inside, "z": z,
                         "points": (error <= radius).tolist(),
                         "worst": (error[worst] <= radius[worst]).tolist(),
                         "rms_error": float(np.sqrt(np.mean(error**2))), "stated_max": float(radius.max()),
                         "file_max": float(cal.uncertainty.get(file_figure(model), np.nan)),
                         "ratio": (error / radius).tolist(), "parts": parts, "beyond": beyond.tolist()})
    return {"index": index, "rows": out_rows}


def file_figure(model: str) -> str:
    """The figure a model's file states for what it answers for: |B|'s interval for the scalar fit."""
    return "expanded_norm_error_nt" if model == "scalar" else "expanded_vector_error_nt"


def _parts(cal, best, h, temps, fields) -> dict[str, float]:
    """Mean squares over the validation points of the vector error's two parts, each beside what the file
    states of it: the parameters' (the calibration against the model's best description of the DUT, and
    the field covariance its parameter covariance gives), and the model's (the best description against
    the true field, and the file's model error and thermal state)."""
    model_nt = np.asarray(cal.uncertainty.get("model_error_nt") or np.zeros(3), float)
    state_nt = hysteresis_state_nt(cal)
    stated = np.mean(np.einsum("nii->n", field_covariance(cal, h, temps)))
    described = best.apply(h, temps)
    return {"parameters": float(np.mean(np.sum((cal.apply(h, temps) - described) ** 2, axis=1))),
            "parameters_stated": float(stated - np.sum(model_nt**2) - np.sum(state_nt**2)),
            "model": float(np.mean(np.sum((described - fields) ** 2, axis=1))),
            "model_stated": float(np.sum(model_nt**2) + np.sum(state_nt**2))}


def _judged(cal, h, temps, fields) -> tuple[np.ndarray, np.ndarray]:
    """(the calibrated field's error at each validation point, what the file states will hold it with 95 %
    probability): the vector error and its 3-D radius; for the scalar fit, the error of |B| and the 95 %
    interval of |B|'s error (rig apply --uncertainty's u_norm)."""
    calibrated = cal.apply(h, temps)
    if cal.model != "scalar":
        return np.linalg.norm(calibrated - fields, axis=1), expanded_at(cal, h, temps)[1]
    size_error = np.abs(np.linalg.norm(calibrated, axis=1) - np.linalg.norm(fields, axis=1))
    return size_error, expanded_norm_at(cal, h, temps)


def coverage(worlds: int, seed: int, out: Path, jobs: int, wider: float = WIDER, table: bool = False,
             field_order: str | None = None, model: str = "t24", again: bool = False,
             temperatures: list[float] | None = None) -> None:
    start = time.perf_counter()
    jobs_args = [(seed, i, str(out), wider, table, field_order, model, again, temperatures)
                 for i in range(worlds)]
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as pool:
            results = list(pool.map(one_world, jobs_args))
    else:
        results = [one_world(a) for a in jobs_args]
    rows = [r for res in results for r in res["rows"] if "unstated" not in r]
    unstated = [r for res in results for r in res["rows"] if "unstated" in r]
    if unstated:
        print(f"  {len(unstated)} DUTs left out, whose calibration states no uncertainty or did not fit:")
        reasons: dict[str, list[str]] = {}
        for r in unstated:
            reasons.setdefault(r["unstated"][:160], []).append(f"world{r['world']:02d} {r['dut']}")
        for said, where in reasons.items():
            print(f"    {len(where)} ({', '.join(where[:4])}{', ...' if len(where) > 4 else ''}): {said}")
    for res in results:
        if res.get("error"):
            print(f"  world {res['index']} not run: {res['error']}")
    print(f"coverage: {len(rows)} DUTs on {worlds} {'turntable ' if table else ''}worlds (seed {seed}; "
          f"systematic errors {wider:g} x the standard uncertainties stated; field order "
          f"{field_order or 'the plan default'}; sessions in {out}; "
          f"{time.perf_counter() - start:.0f} s)")
    if not rows:
        print("  no DUT states an uncertainty: nothing to judge")
        return
    print(f"  true {model.upper()} parameters within U = k u (k from the effective degrees of freedom):")
    total = []
    for g in MODEL_GROUPS[model]:
        values = [v for r in rows for v in r["inside"].get(g, [])]  # a group some fits do not have
        zs = np.array([v for r in rows for v in r["z"].get(g, [])])
        if not values:
            continue
        total += values
        print(f"    {g:6s} {np.mean(values):6.1%} of {len(values):5d}   |error| / u: median "
              f"{np.median(zs):.2f}, 95th percentile {np.quantile(zs, 0.95):.2f}")
    print(f"    all    {np.mean(total):6.1%} of {len(total)}")
    points = [v for r in rows for v in r["points"]]
    worst = [v for r in rows for v in r["worst"]]
    ratio = np.array([v for r in rows for v in r["ratio"]])
    judged = "error of |B| within its stated 95 % interval" if model == "scalar" else \
        "vector error within the stated 95 % radius"
    print(f"  true {judged} at the validation points: "
          f"{np.mean(points):.1%} of {len(points)}; at each DUT's worst {WORST_SHARE:.0%} (largest stated "
          f"radius): {np.mean(worst):.1%} of {len(worst)}")
    print(f"  error / radius: median {np.median(ratio):.2f}, 95th percentile {np.quantile(ratio, 0.95):.2f}; "
          f"per DUT: RMS true error median {np.median([r['rms_error'] for r in rows]):.1f} nT, stated "
          f"{file_figure(model)} median {np.nanmedian([r['file_max'] for r in rows]):.1f} nT")
    beyond = np.array([v for r in rows for v in r["beyond"]], bool)
    if beyond.any():
        inside = np.array(points, bool)
        print(f"  within the directions each calibration took: {np.mean(inside[~beyond]):.1%} of "
              f"{int((~beyond).sum())}; beyond them (rig apply warns): {np.mean(inside[beyond]):.1%} of "
              f"{int(beyond.sum())}")
    parts = [r["parts"] for r in rows if r.get("parts")]
    if parts:
        ms = {k: float(np.mean([p[k] for p in parts])) for k in parts[0]}
        print(f"  the vector error at the validation points, RMS actual / stated: the parameters' part "
              f"{np.sqrt(ms['parameters']):.1f} / {np.sqrt(ms['parameters_stated']):.1f} nT, the model's "
              f"(and thermal state's) {np.sqrt(ms['model']):.1f} / {np.sqrt(ms['model_stated']):.1f} nT")
    per_world = {}
    for r in rows:
        per_world.setdefault(r["world"], []).extend(r["points"])
    shares = " ".join(f"{np.mean(v):.0%}" for _, v in sorted(per_world.items()))
    print(f"  per world, points covered: {shares}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("part", choices=("coverage", "timing", "certificates"))
    parser.add_argument("--worlds", type=int, default=20)
    parser.add_argument("--seed", type=int, default=24)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--wider", type=float, default=WIDER,
                        help="coverage: the worlds' systematic errors, x the standard uncertainties stated")
    parser.add_argument("--table", action="store_true", help="coverage: a turntable in the coils' place")
    parser.add_argument("--field-order", choices=("shuffled", "listed"), default=None,
                        help="coverage: the plan's field_order (default: the plan's default, shuffled)")
    parser.add_argument("--model", choices=sorted(MODEL_GROUPS), default="t24",
                        help="coverage: the model fitted and judged (default t24)")
    parser.add_argument("--again", action="store_true",
                        help="coverage: judge the sessions already in --out again (the same seed draws the "
                             "same worlds), without running them")
    parser.add_argument("--temperatures", default=None,
                        help="coverage: the plan's temperature steps, degC, comma-separated (default: the "
                             "demo plan's)")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--before", default=None, help="timing: also this commit's code, for comparison")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix=f"magrig-uncertainty-{args.part}-"))
    out.mkdir(parents=True, exist_ok=True)
    if args.part == "coverage":
        temperatures = None if args.temperatures is None else [float(v) for v in args.temperatures.split(",")]
        coverage(args.worlds, args.seed, out, args.jobs, args.wider, args.table, args.field_order, args.model,
                 args.again, temperatures)
    elif args.part == "timing":
        from bench.uncertainty_timing import timing

        timing(out, args.before)
    else:
        from bench.uncertainty_timing import certificates

        certificates(out)
    if args.out is None and args.part != "certificates":
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
