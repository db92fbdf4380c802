"""A session file built through the store API from calib's synthetic T24 data (tests and the report
benchmark).

Temperature-major points like a coil campaign (T01-F01 ...), every DUT sampled at every point, with
optional outliers, flagged (saturated) samples, an unstable step, a failed point and a settle timeout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib import synthetic
from drivers.clock import SimClock
from rig.schedules.compile import point_id
from rig.session.events import Kind, Reason
from rig.session.rows import SampleRow
from rig.session.writer import Session

FIELD_NT = 50_000.0


@dataclass(frozen=True)
class SynthPoint:
    id: str
    index: int
    temp_index: int
    setpoint_c: float
    field_index: int
    target: dict


@dataclass
class SynthOptions:
    temps_c: tuple[float, ...] = (-30.0, 0.0, 25.0, 50.0)
    directions: int = 26  # 26: the cube's neighbours; else random directions
    field_vectors_nt: np.ndarray | None = None  # (M, 3): use these instead (e.g. a plan's field set)
    samples: int = 5
    duts: tuple[str, ...] = ("dut1",)
    noise_nt: float = 10.0
    outlier_fraction: float = 0.0
    saturated_points: tuple[str, ...] = ()  # point ids whose first sample of the first DUT is flagged
    timeout_step: int | None = None  # this temperature step has one settle timeout (hold), then settles
    abort_at_step: int | None = None  # this step never settles: 3 timeouts, then the run aborts
    failed_point: str | None = None  # recorded as failed instead of done
    finish: str | None = "completed"
    seed: int = 1


def build_session(path: Path, opts: SynthOptions | None = None) -> dict:
    """Write the session file; returns {dut: true synthetic Calibration}."""
    o = opts or SynthOptions()
    rng = np.random.default_rng(o.seed)
    if o.field_vectors_nt is None:
        dirs = synthetic.coil_directions(o.directions, rng)
    else:
        dirs = np.asarray(o.field_vectors_nt, float) / FIELD_NT  # unit-free, |dirs| carries the magnitude
    data, truths = {}, {}
    for dut in o.duts:
        ds, truth = synthetic.t24_dataset(
            rng,
            temps_c=o.temps_c,
            directions=dirs,
            samples_per_point=o.samples,
            noise_nt=o.noise_nt,
            outlier_fraction=o.outlier_fraction,
        )
        data[dut], truths[dut] = ds, truth
    nt, nf = len(o.temps_c), len(dirs)
    points = [
        SynthPoint(
            point_id(ti + 1, fi + 1, nt, nf),
            ti * nf + fi,
            ti + 1,
            o.temps_c[ti],
            fi + 1,
            {"field_nt": (FIELD_NT * dirs[fi]).tolist()},
        )
        for ti in range(nt)
        for fi in range(nf)
    ]
    clock = SimClock()
    session = Session.create(
        path,
        plan_text="name: synth\n",
        station_text="name: simstation\n",
        plan_name="synth",
        station_name="simstation",
        points=points,
        simulated={"chamber": True, "coils": True},
        operator="test",
        clock=clock,
    )
    with session:
        settle: dict = {}
        for p in points:
            if p.field_index == 1:  # a new temperature step: wait for stability, as the campaign does
                if p.temp_index in (o.timeout_step, o.abort_at_step):
                    _log_timeouts(session, p, 3 if p.temp_index == o.abort_at_step else 1)
                if p.temp_index == o.abort_at_step:
                    session.finish("aborted", f"point {p.id}: gave up after 3 retakes",
                                   code=Reason.RETAKES_EXHAUSTED)
                    return truths
                waited_s = 1800.0 + 60 * p.temp_index
                clock.sleep(waited_s)
                session.log_event(Kind.STABLE, f"stable after {waited_s:.0f} s", code=Reason.STABLE)
                settle = {"target_c": p.setpoint_c, "waited_s": waited_s, "duts": {d: {} for d in o.duts}}
            if p.id == o.failed_point:
                session.mark_point_failed(p.id, "coil compliance fault")
                continue
            rows = []
            for dut, ds in data.items():
                for k, i in enumerate(range(p.index * o.samples, (p.index + 1) * o.samples)):
                    clock.sleep(0.1)
                    flagged = p.id in o.saturated_points and k == 0 and dut == o.duts[0]
                    rows.append(
                        SampleRow(
                            dut=dut,
                            t=clock.now(),
                            field_nt=tuple(ds.h_nt[i]),
                            ref_field_nt=tuple(ds.ref_nt[i]),
                            temp_c=float(ds.temp_c[i]),
                            flags=frozenset({"saturated"} if flagged else ()),
                        )
                    )
            session.record_point(p.id, rows, settle)
        if o.finish:
            completed = o.finish == "completed"
            session.finish(o.finish, "all points taken" if completed else "stopped",
                           code=Reason.COMPLETED if completed else Reason.OPERATOR_ABORT)
    return truths


def _log_timeouts(session: Session, p: SynthPoint, n: int) -> None:
    """Settle-timeout holds of dut1, typed as the engine records them (the wording is free text)."""
    for retake in range(1, n + 1):
        session.clock.sleep(10800.0)
        session.log_event(Kind.HOLD, f"synthetic stability timeout, retake {retake}",
                          code=Reason.STABILITY_TIMEOUT,
                          point_id=p.id, device="dut1", level="WARNING", retake=retake)
