"""Small synthetic session files for the fleet tests and bench, written through rig.session.writer.Session.

Each session: a few temperature steps x the 6 axis directions x a few samples, for one or more DUTs
with T24 errors from calib.synthetic. Deterministic from `seed`, so a session can be written in part
(a campaign still running) and grown later with the same data.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import numpy as np

from calib import synthetic
from drivers.clock import SimClock
from rig.schedules.compile import point_id
from rig.session.rows import SampleRow
from rig.session.writer import Session

FIELD_NT = 50_000.0
AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


@dataclass(frozen=True)
class Point:
    id: str
    index: int
    temp_index: int
    setpoint_c: float
    field_index: int
    target: dict


@dataclass(frozen=True)
class Spec:
    seed: int = 1
    station: str = "rig-a"
    duts: tuple[str, ...] = ("dut1",)
    serials: tuple[str | None, ...] = ()  # one per DUT: recorded in its device snapshot
    temps_c: tuple[float, ...] = (0.0, 25.0, 50.0)
    directions: int = 14  # 6: the axes; otherwise random directions from the seed
    samples: int = 2
    day: dt.date = dt.date(2026, 3, 2)  # the wall-clock date the session was started

    def points(self) -> list[Point]:
        nt, nf = len(self.temps_c), len(self.field_dirs())
        return [
            Point(point_id(ti + 1, fi + 1, nt, nf), ti * nf + fi, ti + 1, self.temps_c[ti], fi + 1,
                  {"field_nt": (FIELD_NT * self.field_dirs()[fi]).tolist()})
            for ti in range(nt) for fi in range(nf)
        ]

    def field_dirs(self) -> np.ndarray:
        if self.directions == 6:
            return AXES
        return synthetic.coil_directions(self.directions, np.random.default_rng(self.seed + 10_000))

    def data(self) -> dict:
        rng = np.random.default_rng(self.seed)
        return {
            dut: synthetic.t24_dataset(rng, temps_c=self.temps_c, directions=self.field_dirs(),
                                       samples_per_point=self.samples, noise_nt=5.0)[0]
            for dut in self.duts
        }


def write_session(path: Path, spec: Spec = Spec(), *, upto: int | None = None, finish: bool = True) -> Path:
    """Create the session file and record its first `upto` points (all by default)."""
    wall = dt.datetime.combine(spec.day, dt.time(8, spec.seed % 60), dt.UTC).timestamp()
    clock = SimClock(start=wall)
    # The store takes the wall-clock start from time.time(); a test session is dated by its spec.
    with mock.patch("rig.session.writer.time.time", return_value=wall):
        session = Session.create(
            path, plan_text=f"name: fleet-synth\nseed: {spec.seed}\n", station_text=f"name: {spec.station}\n",
            plan_name="fleet-synth", station_name=spec.station, points=spec.points(),
            simulated={"chamber": True, "coils": True}, operator="test", clock=clock,
        )
    with session:
        for dut, serial in zip(spec.duts, spec.serials, strict=False):
            session.record_snapshot(dut, {"name": dut, "kind": "magnetometer", "serial_number": serial})
        session.log_event("start", "started", simulated=True)
    return record_points(path, spec, upto=upto, finish=finish)


def record_points(path: Path, spec: Spec = Spec(), *, upto: int | None = None, finish: bool = True) -> Path:
    """Record the points not yet done, up to `upto`; finish the session when every point is done."""
    points = spec.points()
    upto = len(points) if upto is None else upto
    data = spec.data()
    with Session.open(path, clock=SimClock(start=2e9)) as session:
        done = session.done_point_ids()
        for p in points[:upto]:
            if p.id in done:
                continue
            rows = []
            for dut, ds in data.items():
                for i in range(p.index * spec.samples, (p.index + 1) * spec.samples):
                    rows.append(SampleRow(dut=dut, t=1e9 + i, field_nt=tuple(ds.h_nt[i]),
                                          ref_field_nt=tuple(ds.ref_nt[i]), temp_c=float(ds.temp_c[i])))
            session.record_point(p.id, rows, {"target_c": p.setpoint_c})
        if finish and upto == len(points):
            session.finish("completed", "all points taken")
    return path


def write_sessions(folder: Path, n: int, **spec) -> list[Path]:
    """`n` sessions seeded 1..n in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    return [write_session(folder / f"s{seed:04d}.session", Spec(seed=seed, **spec))
            for seed in range(1, n + 1)]
