"""Chamber time and held-out error of the step plan, the continuous ramp and the designed plans on one
simulated station (default configs/stations/sim-4.yaml: four DUTs lagging the air by 300..900 s, probes
lagging the DUTs, random truths with non-zero K and kb).

Plans: configs/plans/full-campaign.yaml (steps), configs/plans/ramp-campaign.yaml (continuous ramp), the
plan `rig design --from` the step session makes of configs/plans/sequential-campaign.yaml for this station
(designed: planned on what the step session measured, never on the station's `sim:`), and
configs/plans/sequential-campaign.yaml itself (decided during the run, measuring its DUTs itself). The
designed and sequential plans aim at the standard errors the step plan is predicted to reach on this
station with the noise its session measured (calib/design/optimal.py), so the comparison is at equal
precision;
--targets plan keeps the plan's own stop_when instead. Each plan's `rig check` estimate is printed beside
the chamber time its run took.

For each plan: the simulated chamber time (session start to end), each DUT's held-out vector error on a
separate validation campaign (other directions, temperatures between the steps) against the simulator's
true field for the same raw readings (the calibration's own error; against the recorded reference, noise
included, in brackets), and each DUT's largest standard errors (S, K, b, kb) as the fit reports them.
Goal: chamber time <= 0.25 of the step plan's, held-out error <= 1.1 x the step plan's. A DUT without a
SET/RESET pair (an HMC5883L) reads its bridge offset, which drifts some 20 nT/degC: the validation's own
temperatures (a probe a fraction of a degree off the element even when stable) then put a floor of a few
nT under every plan's error against the truth, the same for all of them.

    .venv/bin/python bench/design.py [--station S] [--out DIR] [--targets step|plan]   (about 15 min)
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from calib.calibration import Calibration
from calib.design.optimal import information, std_errors
from rig.config.loading import load_campaign
from rig.devices.simulated.world import (
    dut_truths,  # the truth the held-out errors are judged against, nothing else
)
from rig.planning.design import design_inputs, design_plan, designed_plan_text
from rig.planning.inputs import planning_inputs
from rig.run.campaign import run_campaign
from rig.schedules.compile import check_campaign, compile_plan
from rig.session.reader import SessionReader, read_dataset

# as `rig` itself does: a timed-out request is the rig's to retry and log, not pymodbus's to print raw frames
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

REPO = Path(__file__).resolve().parents[1]
PLANS = REPO / "configs" / "plans"
STATION = REPO / "configs" / "stations" / "sim-4.yaml"
BETWEEN = [-22.5, -7.5, 7.5, 20, 32.5, 47.5, 62.5]  # validation temperatures, between the steps
VALIDATION = {"name": "validation", "temperatures": {"steps": BETWEEN, "ramp_c_per_min": 3.0, "stability":
              {"band_c": 0.3, "rate_c_per_min": 0.05, "dwell_s": 600, "max_wait_s": 10800}},
              "fields": {"kind": "fibonacci", "n": 20, "magnitude_nt": 45000}, "samples_per_point": 4,
              "settle_s": 1.0, "fit": {"models": ["t24"]}}
GROUPS = {"S": "S", "K": "K", "b": "b_nt", "kb": "kb_nt_per_c"}


def run(plan_path: Path, station: Path, out: Path, name: str) -> Path:
    session = out / f"{name}.session"
    if session.exists():
        with SessionReader(session) as reader:
            if reader.info()["completed"]:
                print(f"  {name}: kept from {session}")
                return session
        session.unlink()
    start = time.perf_counter()
    outcome = run_campaign(campaign=load_campaign(plan_path, station), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    print(f"  {name}: {outcome.result.points_done} points in {time.perf_counter() - start:.0f} s wall")
    return session


def step_targets(station: Path, margin: float, step_session: Path) -> dict[str, float]:
    """`margin` x the largest standard errors the step plan is predicted to reach on this station (every
    DUT at each setpoint, its noise as the step session measured it). The held-out error of one campaign
    scatters by some 20 % around its expectation, so matching the step plan's precision exactly would fail
    the 1.1 x goal on one DUT or another about half the time: the designed plans aim a margin below it."""
    campaign = load_campaign(PLANS / "full-campaign.yaml", station)
    points = compile_plan(campaign.plan, campaign.station)
    fields = np.array([campaign.station.field_source.nominal_field_nt(p.command) for p in points])
    temps = np.array([p.setpoint_c for p in points])
    gram = information(fields, temps, campaign.plan.samples_per_point, temp_ref_c=20.0)
    measured = planning_inputs(campaign.plan, campaign.station, step_session)
    se = std_errors(gram, max(d.noise_nt for d in measured.duts.values()), 20.0)
    return {g: float(f"{margin * np.max(se[k]):.2g}") for g, k in GROUPS.items()}


def with_targets(plan_path: Path, targets: dict[str, float] | None, out: Path, name: str,
                 samples: int | None = None) -> Path:
    data = yaml.safe_load(plan_path.read_text())
    data.pop("station", None)
    if targets is not None:
        data["stop_when"] = targets
    if samples is not None:
        data["samples_per_point"] = samples
    path = out / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def designed(sequential: Path, station: Path, out: Path, session: Path) -> tuple[Path, int]:
    """`rig design --from SESSION` of the sequential plan for this station: the designed plan, and its
    samples per point (the sequential plan then takes as many: the station's pace decides it, not the
    shipped file)."""
    campaign = load_campaign(sequential, station)
    inputs = design_inputs(campaign.plan, campaign.station, session)
    result = design_plan(campaign.plan, campaign.station, inputs)
    path = out / "designed.yaml"
    path.write_text(designed_plan_text(campaign.plan_text, result, campaign.station, name="designed",
                                       station_ref=None, made_for="bench/design.py"))
    legs = ", ".join(f"{leg.to_c:g} x {leg.sweeps}" for leg in result.schedule.legs)
    print(f"  designed: {len(result.targets_nt)} fields x {result.samples} samples, legs {legs}; predicted "
          f"{result.schedule.duration_s / 3600:.2f} h, {result.schedule.message}")
    return path, result.samples


def chamber_hours(session: Path) -> float:
    with SessionReader(session) as reader:
        info = reader.info()
    return (info["ended"] - info["started"]) / 3600.0


def t24_of(session: Path, dut: str) -> Calibration:
    """The session's own T24 calibration, as `rig run` fitted it (lag-corrected where the temperature
    moved)."""
    with SessionReader(session) as reader:
        fits = [f for f in reader.fits() if f["dut"] == dut and f["model"] == "t24"]
    import json

    return Calibration.from_dict(json.loads(fits[-1]["calibration_json"]))


def expected_held_out_nt(session: Path, validation: Path, dut: str) -> float:
    """The RMS held-out error the session's own data predicts (sigma^2 G^-1 at the validation rows, three
    axes): the expectation around which one campaign's held-out error scatters."""
    from calib.design.optimal import covariance
    from calib.equations import t24_regressors
    from calib.models.gram import GramAccumulator
    from rig.analysis.lagfit import lag_corrected, session_is_ramp

    ds = read_dataset(session, dut)
    if session_is_ramp(session):
        ds, _ = lag_corrected(ds)
    acc = GramAccumulator(20.0)
    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    sigma2 = sum(v**2 for v in acc.solve().stats["sigma_nt"].values())
    val = read_dataset(validation, dut)
    x = t24_regressors(val.h_nt, val.temp_c, 0.0)
    cov = covariance(acc.gram[:8, :8], 20.0)  # absolute tau: x at tau itself
    return float(np.sqrt(sigma2 * np.einsum("ni,ij,nj->n", x, cov, x).mean()))


def held_out_nt(cal: Calibration, validation: Path, dut: str, truth, pair: bool) -> tuple[float, float]:
    """RMS vector error on the validation rows against the simulator's true field for the same raw readings
    (a DUT without a SET/RESET pair reads its bridge offset too), and against the recorded reference."""
    ds = read_dataset(validation, dut)
    calibrated = cal.apply(ds.h_nt, ds.temp_c)
    true = np.array([truth.field_from_raw(h if pair else h - truth.bridge_offset_at(t), t)
                     for h, t in zip(ds.h_nt, ds.temp_c, strict=True)])
    return tuple(float(np.sqrt(np.mean(np.sum((calibrated - x) ** 2, axis=1)))) for x in (true, ds.ref_nt))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--station", type=Path, default=STATION)
    parser.add_argument("--out", type=Path, help="keep the sessions here (reused when complete)")
    parser.add_argument("--targets", choices=["step", "plan"], default="step")
    parser.add_argument("--margin", type=float, default=0.7, help="targets: this x the step plan's predicted")
    parser.add_argument("--skip", nargs="*", default=[],
                        help="plans to leave out (step ramp designed sequential)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        station = args.station.resolve()
        step_session = run(PLANS / "full-campaign.yaml", station, out, "step")  # it measures the station too
        targets = step_targets(station, args.margin, step_session) if args.targets == "step" else None
        aim = (", ".join(f"{k} {v:g}" for k, v in targets.items()) + f" ({args.margin:g} x the step plan's "
               "predicted)") if targets else "the plan's stop_when"
        print(f"station {station.name}; targets: {aim}")
        sequential = with_targets(PLANS / "sequential-campaign.yaml", targets, out, "sequential")
        designed_path, samples = designed(sequential, station, out, step_session)
        sequential = with_targets(sequential, None, out, "sequential", samples)
        plans = {"step": PLANS / "full-campaign.yaml", "ramp": PLANS / "ramp-campaign.yaml",
                 "designed": designed_path, "sequential": sequential}
        plans = {k: v for k, v in plans.items() if k not in args.skip}
        validation = out / "validation.yaml"
        validation.write_text(yaml.safe_dump(VALIDATION, sort_keys=False))
        sessions = {name: run(path, station, out, name) for name, path in plans.items()}
        sessions["validation"] = run(validation, station, out, "validation")
        checked = load_campaign(validation, station)
        truths = dut_truths(checked.station)
        pairs = {d.name: checked.plan.set_reset == "pair" and bool(getattr(d.options, "set_reset", False))
                 for d in checked.station.duts}
        hours = {name: chamber_hours(s) for name, s in sessions.items() if name != "validation"}
        estimate_h = {name: check_campaign(load_campaign(plans[name], station)).duration_s / 3600.0
                      for name in hours}
        errors = {name: {dut: held_out_nt(t24_of(s, dut), sessions["validation"], dut, truths[dut],
                                          pairs[dut])
                         for dut in truths} for name, s in sessions.items() if name != "validation"}
        expected = {name: {dut: expected_held_out_nt(s, sessions["validation"], dut) for dut in truths}
                    for name, s in sessions.items() if name != "validation"}
        print("\n| plan | chamber time | rig check | / step | held-out error vs truth, nT (per DUT) "
              "| worst / step | expected, nT | worst / step |")
        print("|---|---|---|---|---|---|---|---|")
        step_err, step_exp = errors.get("step"), expected.get("step")
        for name in hours:
            per_dut = " ".join(f"{errors[name][d][0]:.2f}" for d in truths)
            ratio = (max(errors[name][d][0] / step_err[d][0] for d in truths) if step_err else float("nan"))
            exp = " ".join(f"{expected[name][d]:.2f}" for d in truths)
            exp_ratio = (max(expected[name][d] / step_exp[d] for d in truths) if step_exp else float("nan"))
            rel = hours[name] / hours["step"] if "step" in hours else float("nan")
            print(f"| {name} | {hours[name]:.2f} h | {estimate_h[name]:.2f} h | {rel:.2f} | {per_dut} "
                  f"| {ratio:.2f} | {exp} | {exp_ratio:.2f} |")
        print("\nheld-out error against the validation reference (noise included), nT: "
              + "; ".join(f"{n} " + " ".join(f"{errors[n][d][1]:.1f}" for d in truths) for n in hours))
        print("\nlargest standard errors as fitted (S, K per degC, b nT, kb nT/degC):")
        print("| plan | DUT | S | K | b | kb |")
        print("|---|---|---|---|---|---|")
        for name, s in sessions.items():
            if name == "validation":
                continue
            for dut in truths:
                se = t24_of(s, dut).std_errors
                cells = " | ".join(f"{np.max(se[k]):.2g}" for k in GROUPS.values())
                print(f"| {name} | {dut} | {cells} |")


if __name__ == "__main__":
    main()
