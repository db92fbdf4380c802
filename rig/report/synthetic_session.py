"""A session file built through the store API from calib's synthetic T24 data (tests, benchmark, demos).

Temperature-major points like a coil campaign (T01-F01 ...), every DUT sampled at every point, with
optional outliers, flagged (saturated) samples, an unstable step, a failed point and a settle timeout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib import synthetic
from rig.clock import SimClock
from rig.plan import point_id
from rig.store import SampleRow, Session

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
    unstable_step: int | None = None  # temperature index whose settle stats say it timed out
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
        for p in points:
            rows_of_point = slice(p.index * o.samples, (p.index + 1) * o.samples)
            if p.id == o.failed_point:
                session.mark_point_failed(p.id, "coil compliance fault")
                continue
            rows = []
            for dut, ds in data.items():
                for k, i in enumerate(range(*rows_of_point.indices(len(ds)))):
                    clock.sleep(0.1)
                    flags = (
                        {"saturated"} if p.id in o.saturated_points and k == 0 and dut == o.duts[0] else set()
                    )
                    rows.append(
                        SampleRow(
                            dut=dut,
                            t=clock.now(),
                            field_nt=tuple(ds.h_nt[i]),
                            ref_field_nt=tuple(ds.ref_nt[i]),
                            temp_c=float(ds.temp_c[i]),
                            flags=frozenset(flags),
                        )
                    )
            first = p.field_index == 1
            timed_out = first and p.temp_index == o.unstable_step
            settle = (
                {"settle_s": 1800.0 + 60 * p.temp_index, "state": "timeout" if timed_out else "stable"}
                if first
                else {}
            )
            if timed_out:
                session.log_event(
                    "settle_timeout",
                    f"step {p.temp_index}: DUT temperature not stable after 4 h (settle timeout)",
                    level="WARNING",
                )
            session.record_point(p.id, rows, settle)
        if o.finish:
            session.finish(o.finish, "all points taken" if o.finish == "completed" else "stopped")
    return truths
