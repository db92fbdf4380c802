"""The model judged, not assumed: T24's model checks decide. Acceptance fails a DUT whose check fails where
the judged model does not capture it; a failed linearity in temperature brings a T36, judged when it
validates better; a sequential run whose check fails adds interior temperatures instead of finishing.

The synthetic effects are many times the noise over thousands of samples (each check's statistic is
then tens of standard deviations beyond its threshold), and a T24 DUT's checks fail by chance with
p < 1e-3 per check only where also larger than half the noise, which pure noise never is."""

from __future__ import annotations

import json

import numpy as np

import calib
from calib.checks.model_checks import FIELD, HYSTERESIS, TEMPERATURE
from calib.dataset import Dataset
from calib.design.planner import CHECK, END, ChamberModel, DutModel, Leg, Pace, State, predict
from calib.design.sequential import interior_temperatures, next_leg
from calib.synthetic import coil_directions, random_t24_params, t24_dataset
from rig.analysis.acceptance import Verdict, model_check_findings
from rig.analysis.judged import judged_for_dut
from rig.analysis.tempchoice import record_temperature_model, share_choice, wants_t36
from rig.budget.modelerror import record_model_checks
from rig.config import Plan
from rig.schedules.sequential_checks import AddedChecks, decide_with_checks

TEMPS_C = (-30.0, -5.0, 20.0, 45.0, 70.0)


def dataset(seed: int, *, curve_nt_per_c2: float = 0.0, cubic_ppm: float = 0.0) -> Dataset:
    """T24 data at TEMPS_C and two field magnitudes (25 and 50 uT), 10 nT noise; optionally a quadratic
    temperature term on the reference (curve x (T - 20)^2 on x and y) or a cubic field term."""
    rng = np.random.default_rng(seed)
    params = random_t24_params(rng)
    parts = [t24_dataset(rng, params=params, temps_c=TEMPS_C, samples_per_point=4, field_nt=f)[0]
             for f in (25_000.0, 50_000.0)]
    h = np.vstack([p.h_nt for p in parts])
    temp = np.concatenate([p.temp_c for p in parts])
    ref = np.vstack([p.ref_nt for p in parts])
    ref = ref + np.outer(curve_nt_per_c2 * (temp - 20.0) ** 2, [1.0, 1.0, 0.0])
    ref = ref + 1e-6 * cubic_ppm * np.sum(h**2, axis=1, keepdims=True) / 50_000.0**2 * h
    return Dataset(h, temp, ref)


def checked(ds: Dataset):
    cal = calib.fit(ds, "t24")
    record_model_checks(cal, ds, None)  # no thermal direction: the hysteresis check cannot run
    record_temperature_model(cal, ds)
    return cal


def test_acceptance_fails_a_check_the_judged_model_does_not_capture_and_passes_a_t24_dut():
    clean = checked(dataset(1))
    failures, not_run = model_check_findings(clean.stats, "t24")
    assert failures == [] and not_run == [HYSTERESIS]
    assert not wants_t36(clean) and "temperature_model" not in clean.stats  # no T36 for a T24 DUT

    cubic = checked(dataset(2, cubic_ppm=2000.0))
    failures, _ = model_check_findings(cubic.stats, "t24")
    assert len(failures) == 1 and failures[0].startswith(f"{FIELD} fails (statistic ")
    assert " dof; p " in failures[0]
    assert model_check_findings(cubic.stats, "t36")[0] == failures  # no model captures a field non-linearity

    line = Verdict("mmc0", "t24", failed=failures, not_run=not_run).line()
    assert line.startswith(f"mmc0 FAIL ({FIELD} fails (statistic ")
    assert line.endswith(f"model checks not run: {HYSTERESIS})")
    assert Verdict("mmc1", "t24", not_run=[HYSTERESIS]).line() == \
        f"mmc1 PASS (model checks not run: {HYSTERESIS})"
    assert model_check_findings({}, "t24") == ([], ["all (no T24 model checks recorded)"])


def test_a_curved_dut_gets_t36_chosen_and_judged_and_its_linearity_failure_captured():
    ds = dataset(3, curve_nt_per_c2=0.03)  # 75 nT at the ends of the range
    cal24 = checked(ds)
    failures, _ = model_check_findings(cal24.stats, "t24")
    assert len(failures) == 1 and failures[0].startswith(f"{TEMPERATURE} fails")
    assert wants_t36(cal24)
    choice = cal24.stats["temperature_model"]
    assert choice["model"] == "t36" and choice["heldout_rms_nt"]["t36"] < choice["heldout_rms_nt"]["t24"]
    assert "linearity in temperature fails" in choice["why"]
    cal36 = calib.fit(ds, "t36")
    share_choice(cal24, cal36)
    assert cal36.stats["temperature_model"] == choice
    assert judged_for_dut("t24", {"t24": cal24, "t36": cal36}) == "t36"
    assert judged_for_dut("t24", {"t24": cal24.to_dict(), "t36": cal36.to_dict()}) == "t36"  # recorded form
    assert judged_for_dut("p12", {"t24": cal24, "t36": cal36, "p12": None}) == "p12"  # the plan judges p12
    assert model_check_findings(cal24.stats, "t36") == ([], [HYSTERESIS])  # captured by the judged T36
    clean = checked(dataset(4))
    assert judged_for_dut("t24", {"t24": clean, "t36": calib.fit(dataset(4), "t36")}) == "t24"


def test_the_plan_key_defaults_on_and_turns_off():
    base = {"name": "p", "temperatures": {"steps": [0, 20, 40]}, "fields": {"kind": "cube24"},
            "samples_per_point": 2}
    assert Plan.model_validate({**base, "acceptance": {}}).acceptance.model_checks is True
    off = Plan.model_validate({**base, "acceptance": {"model_checks": False}})
    assert off.acceptance.model_checks is False


# --- a sequential run -------------------------------------------------------------------------------------
PACE = Pace(50_000 * coil_directions(26), 20, 4.0)
TARGETS = {"S": 2e-5, "K": 5e-7, "b": 0.6, "kb": 0.015}
CHAMBER = ChamberModel((-30.0, 70.0), 3.0, (20.0,), 1)


def test_interior_temperatures_split_the_largest_gaps_first():
    assert interior_temperatures((70.0, -30.0), [20.0], 2) == [-5.0, 45.0]
    assert interior_temperatures((-30.0, 70.0), [20.0], 1) == [-5.0]
    assert interior_temperatures((-30.0, 70.0), [20.0, -5.0, 45.0], 4) == [-17.5, 7.5, 32.5, 57.5]
    assert interior_temperatures((-30.0, 70.0), [20.0, -5.0], 4) == [45.0]
    assert interior_temperatures((-30.0, 70.0), [20.0], 0) == []


def _finished():
    """A run that has crossed the range and met its targets: next_leg stops."""
    models = [DutModel("d0", 21.0, 300.0), DutModel("d1", 21.0, 600.0)]
    legs = [Leg(70.0, 14, 3.0, END, 22.0), Leg(20.0, 18, 3.0, CHECK, 70.0), Leg(-30.0, 30, 3.0, END, 20.0)]
    pred = predict(State.start(models, 22.0), legs, PACE, models, 20.0)
    state = pred.state(len(pred.t_s) - 1)

    def decide(chamber):
        return next_leg(state, legs, models, chamber, PACE, TARGETS, max_duration_s=12 * 3600,
                        ratios_now={"d0": 0.5, "d1": 0.5})
    return decide


def test_a_failing_linearity_check_adds_interior_temperatures_instead_of_finishing():
    decide = _finished()
    assert decide(CHAMBER).stop  # the targets are met and the checks done
    clean = {"d0": dataset(5), "d1": dataset(6)}
    decision, found = decide_with_checks(AddedChecks(2), CHAMBER, decide, lambda: clean)
    assert decision.stop and found is None

    curved = {"d0": dataset(7, curve_nt_per_c2=0.03), "d1": dataset(8)}
    added = AddedChecks(2)
    decision, found = decide_with_checks(added, CHAMBER, decide, lambda: curved)
    assert not decision.stop and decision.new_leg
    assert decision.leg.kind == CHECK and decision.leg.to_c == -5.0  # the nearer added one, from -30
    assert found["check"] == TEMPERATURE and set(found["failed"]) == {"d0"}
    assert json.loads(json.dumps(found)) == found  # recorded with the decision as JSON
    assert found["failed"]["d0"]["p"] < 1e-3 and found["added_c"] == [-5.0, 45.0]
    assert added.added_c == [-5.0, 45.0] and added.chamber(CHAMBER).checks_c == (-5.0, 20.0, 45.0)
    assert "linearity in temperature fails (d0 p" in decision.reason
    assert "-5, 45 degC added" in decision.reason

    # the bound reached: the check's failure is recorded, nothing more is added, the run may finish
    decision, found = decide_with_checks(AddedChecks(2, [-5.0, 45.0]), CHAMBER,
                                         lambda chamber: decide(CHAMBER), lambda: curved)
    assert decision.stop and found["added_c"] == [] and "none more" in decision.reason


def test_max_added_checks_zero_adds_none():
    decide = _finished()
    decision, found = decide_with_checks(AddedChecks(0), CHAMBER, decide,
                                         lambda: {"d0": dataset(9, curve_nt_per_c2=0.03)})
    assert decision.stop and found["added_c"] == []
