"""Many DUTs on one campaign (configs/stations/sim-64.yaml: 60 MMC5983MA behind eight TCA9548A switches
on one bus, 4 serial magnetometers on two shared lines, a TMP117 beside each; all simulated).

1. One point's reading (SAMPLES x every temperature sensor, the coil readback, every DUT) for 1, 4, 16
   and 64 DUTs: each DUT read in turn against the interleaved reading the campaign does
   (rig/devices/interleave.py); wall and simulated seconds per point.
2. A short campaign (the demo plan's 26 fields at two temperatures) on 4 and on 64 DUTs, each in a new
   process: wall time per point in the engine's run and its parts (device I/O, the point's session
   transaction, the live fits, everything else), the live view's render, the post-run fits (T24, P12 per
   DUT), simulated seconds per point, and the process's peak memory (max RSS); then the 64/4 ratios.
3. Chamber minutes per DUT on sim-64 for the demo plan, the ramp plan and the plan `rig design` makes for
   sim-64 from sequential-campaign.yaml `--from` a short measuring session on sim-64 (`rig check`'s
   estimate / 64).
4. `rig check`'s duration against the run's, on sim-4 and on sim-64: a short step session measures the
   station (its pace, its chamber, its DUTs), `rig design --from` it makes a small designed plan (its
   stop_when left out, so that it runs whole), `rig check` predicts it and it runs; the measuring session
   itself, checked at the drivers' stated pace and without measured lags, for contrast.

    .venv/bin/python bench/many_duts.py [--skip-campaign] [--skip-timing]
"""

from __future__ import annotations

import functools
import io
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import yaml  # noqa: E402
from rich.console import Console  # noqa: E402

from rig import config as cfg  # noqa: E402
from rig.config.loading import load_campaign  # noqa: E402
from rig.devices.build import open_rig  # noqa: E402
from rig.devices.interleave import read_all  # noqa: E402
from rig.schedules.compile import check_campaign  # noqa: E402

STATION = REPO / "configs" / "stations" / "sim-64.yaml"
PLANS = {"demo": REPO / "configs" / "plans" / "demo.yaml",
         "ramp": REPO / "configs" / "plans" / "ramp-campaign.yaml"}
SAMPLES = 10
COUNTS = (1, 4, 16, 64)
CAMPAIGN_COUNTS = (4, 64)


def subset(station: cfg.Station, n: int) -> cfg.Station:
    """n DUTs of the station, the kinds taken alternately while both last, with their sensors."""
    mmcs = [d for d in station.duts if d.device_type == "mmc5983ma"]
    serials = [d for d in station.duts if d.device_type != "mmc5983ma"]
    mixed = [d for pair in zip(mmcs, serials, strict=False) for d in pair]
    mixed += mmcs[len(serials):] + serials[len(mmcs):]
    names = {d.name for d in mixed[:n]}
    data = station.model_dump(mode="json", exclude_none=True)
    data["duts"] = [d for d in data["duts"] if d["name"] in names]
    data["temperature_sensors"] = [s for s in data["temperature_sensors"] if s["beside"] in names]
    return cfg.Station.model_validate(data)


def one_point(rig, interleaved: bool) -> tuple[float, float]:
    clock = rig.clock
    wall0, sim0 = time.perf_counter(), clock.now()
    for _ in range(SAMPLES):
        if interleaved:
            read_all(rig.temp_sensors, clock)
            rig.field_source.read()
            read_all(rig.duts, clock)
        else:
            for sensor in rig.temp_sensors.values():
                sensor.read()
            rig.field_source.read()
            for dev in rig.duts.values():
                dev.read()
    return time.perf_counter() - wall0, clock.now() - sim0


def reading_table(station: cfg.Station) -> None:
    print(f"1. one point's reading, {SAMPLES} samples; seconds per point (median of 3)")
    print(f"{'DUTs':>6}  {'wall in turn':>12}  {'interleaved':>11}  {'sim in turn':>11}  {'interleaved':>11}")
    for n in COUNTS:
        rig = open_rig(subset(station, n))
        try:
            rows = {mode: sorted(one_point(rig, mode) for _ in range(3))[1] for mode in (False, True)}
        finally:
            rig.close()
        (wb, sb), (wa, sa) = rows[False], rows[True]
        print(f"{n:>6}  {wb:>12.3f}  {wa:>11.3f}  {sb:>11.3f}  {sa:>11.3f}")


class Timers:
    """Wall seconds in wrapped callables, by bucket (a call inside another of its bucket counts once)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.busy: set[str] = set()

    def wrap(self, owner, name: str, bucket: str) -> None:
        fn = getattr(owner, name)

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if bucket in self.busy:
                return fn(*args, **kwargs)
            self.busy.add(bucket)
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.busy.discard(bucket)
                self.seconds[bucket] = self.seconds.get(bucket, 0.0) + time.perf_counter() - t0

        setattr(owner, name, timed)


def short_plan(tmp: Path) -> Path:
    plan = yaml.safe_load(PLANS["demo"].read_text())
    plan["temperatures"]["steps"] = [20, 30]  # two: T24 is identifiable
    plan["temperatures"]["stability"]["dwell_s"] = 60
    plan["fit"] = {"models": ["t24", "p12"]}
    path = tmp / "short.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def campaign_figures(n: int) -> dict:
    """The short campaign on n DUTs of sim-64, in this process (run it in a new one: peak memory)."""
    from rig.analysis import postrun
    from rig.engine.executor import Engine
    from rig.run import campaign, display, runner
    from rig.session.writer import Session

    timers = Timers()
    timers.wrap(runner, "read_all", "device I/O")  # every DUT's and sensor's reading of a sample
    timers.wrap(Session, "record_point", "store")
    timers.wrap(runner.CampaignRunner, "_feed_live", "live fits")
    timers.wrap(postrun, "fit_session", "post-run fits")
    timers.wrap(Engine, "run", "run")
    renders: list[float] = []
    reading_sim_s: list[float] = []
    collect = runner.CampaignRunner.collect_point

    def instrument(rig) -> None:
        for dev in rig.devices():
            if hasattr(dev, "read"):
                timers.wrap(dev, "read", "device I/O")

        def timed_collect(runner, cmd):  # simulated seconds of a point's reading
            t0 = rig.clock.now()
            try:
                return collect(runner, cmd)
            finally:
                reading_sim_s.append(rig.clock.now() - t0)

        runner.CampaignRunner.collect_point = timed_collect

    def live_view(status, run):  # the live panel, rendered after every point into a null console
        view = display.LiveDisplay(status, run, console=Console(file=io.StringIO(), width=120))

        def render(point_id: str) -> None:
            t0 = time.perf_counter()
            view.live.console.print(view.render())
            renders.append(time.perf_counter() - t0)

        run.on_point.append(render)
        return None

    with tempfile.TemporaryDirectory() as tmp:
        station_path = Path(tmp) / "station.yaml"
        station = subset(cfg.load_station(STATION), n)
        station_path.write_text(yaml.safe_dump(station.model_dump(mode="json", exclude_none=True)))
        camp = load_campaign(short_plan(Path(tmp)), station_path)
        outcome = campaign.run_campaign(campaign=camp, session_path=Path(tmp) / "s.session",
                                        on_rig=instrument, display_factory=live_view)
    assert outcome.result.status == "completed", outcome.result
    assert not [f for f in outcome.fits if "error" in f], outcome.fits
    points = outcome.result.points_done
    sec = timers.seconds
    return {
        "duts": n, "points": points,
        "run_ms": 1e3 * sec["run"] / points,
        "io_ms": 1e3 * sec.get("device I/O", 0.0) / points,
        "store_ms": 1e3 * sec["store"] / points,
        "live_ms": 1e3 * sec["live fits"] / points,
        "view_ms": 1e3 * sum(renders) / len(renders),
        "fits_s": sec["post-run fits"],
        "sim_s": sum(reading_sim_s) / len(reading_sim_s),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def campaign_table() -> None:
    print("\n2. short campaign (2 x 26 points, 5 samples, T24 + P12 fits), one new process each")
    rows = []
    for n in CAMPAIGN_COUNTS:
        done = subprocess.run([sys.executable, __file__, "--campaign", str(n)], capture_output=True,
                              text=True, check=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"{'DUTs':>5} {'wall/point':>10} {'device I/O':>10} {'store':>7} {'live fits':>9} {'view':>6} "
          f"{'other':>6} {'sim reading':>11} {'post-run fits':>13} {'peak RSS':>9}")
    for r in rows:
        other = r["run_ms"] - r["io_ms"] - r["store_ms"] - r["live_ms"]
        print(f"{r['duts']:>5} {r['run_ms']:>8.0f}ms {r['io_ms']:>8.0f}ms {r['store_ms']:>5.1f}ms "
              f"{r['live_ms']:>7.1f}ms {r['view_ms']:>4.1f}ms {other:>4.0f}ms {r['sim_s']:>10.3f}s "
              f"{r['fits_s']:>12.2f}s {r['peak_mb']:>6.0f} MB")
    small, big = rows
    ratio = big["duts"] / small["duts"]
    print(f"64 / 4 DUTs ({ratio:.0f}x the DUTs): wall per point {big['run_ms'] / small['run_ms']:.1f}x, "
          f"simulated reading time per point {big['sim_s'] / small['sim_s']:.2f}x, post-run fits "
          f"{big['fits_s'] / small['fits_s']:.1f}x, peak memory {big['peak_mb'] / small['peak_mb']:.2f}x")


MEASURE = {"name": "measure", "fields": {"kind": "cube24", "magnitudes_nt": [50000]}, "samples_per_point": 4,
           "settle_s": 0.5, "fit": {"models": ["t24"]},
           "temperatures": {"steps": [30, 15], "ramp_c_per_min": 5.0,
                            "stability": {"band_c": 0.5, "rate_c_per_min": 0.2, "dwell_s": 60}}}
SMALL = {"name": "small", "samples_per_point": 4, "settle_s": 1.0, "fit": {"models": ["t24"]},
         "fields": {"kind": "directions", "magnitude_nt": 50000,
                    "directions": [[1, 1, 1], [1, 1, -1], [1, -1, 1], [1, -1, -1], [-1, 1, 1], [-1, 1, -1],
                                   [-1, -1, 1], [-1, -1, -1]]},
         "temperatures": {"mode": "sequential", "range_c": [15, 25], "checks_c": [20], "max_duration_h": 6},
         "stop_when": {"S": 1e-4, "K": 5e-6, "b": 5.0, "kb": 0.3}}


def run_for(plan: Path, station: Path, session: Path) -> tuple[float, float]:
    """(the run's chamber seconds, wall seconds)."""
    from rig.run.campaign import run_campaign
    from rig.session.reader import SessionReader

    t0 = time.perf_counter()
    outcome = run_campaign(campaign=load_campaign(plan, station), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    with SessionReader(session) as reader:
        info = reader.info()
    return info["ended"] - info["started"], time.perf_counter() - t0


def measuring_session(station: Path, tmp: Path) -> tuple[Path, float, float]:
    """A short step session that measures the station: (session, rig check's estimate, its run's time)."""
    plan = tmp / "measure.yaml"
    plan.write_text(yaml.safe_dump(MEASURE, sort_keys=False))
    predicted = check_campaign(load_campaign(plan, station)).duration_s
    session = tmp / "measure.session"
    taken, _ = run_for(plan, station, session)
    return session, predicted, taken


def designed_from(source: Path, station: Path, session: Path, out: Path) -> Path:
    """`rig design SOURCE --station STATION --from SESSION -o OUT`."""
    command = ["design", str(source), "--station", str(station), "--from", str(session), "-o", str(out)]
    subprocess.run([sys.executable, "-m", "rig", *command], capture_output=True, text=True, check=True)
    return out


def timing_table() -> None:
    print("\n4. rig check's duration against the run's (simulated chamber time)")
    print(f"{'station':>8} {'plan':>34} {'rig check':>10} {'run':>10} {'run/check':>9} {'wall':>6}")
    for station in (REPO / "configs" / "stations" / "sim-4.yaml", STATION):
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            session, predicted, taken = measuring_session(station, tmp)
            print(f"{station.stem:>8} {'measuring steps (stated pace, no lags)':>34} {predicted:>9.0f}s "
                  f"{taken:>9.0f}s {taken / predicted:>9.3f}")
            small = tmp / "small.yaml"
            small.write_text(yaml.safe_dump(SMALL, sort_keys=False))
            designed = designed_from(small, station, session, tmp / "designed.yaml")
            data = yaml.safe_load(designed.read_text())
            data.pop("stop_when")  # the whole plan runs: its duration is what rig check predicts
            designed.write_text(yaml.safe_dump(data, sort_keys=False))
            predicted = check_campaign(load_campaign(designed, station)).duration_s
            taken, wall = run_for(designed, station, tmp / "designed.session")
            print(f"{station.stem:>8} {'designed --from it (measured pace)':>34} {predicted:>9.0f}s "
                  f"{taken:>9.0f}s {taken / predicted:>9.3f} {wall:>5.0f}s")


def chamber_minutes() -> None:
    print("\n3. chamber time per DUT on sim-64 (rig check's estimate)")
    with tempfile.TemporaryDirectory() as tmp:
        session, _, _ = measuring_session(STATION, Path(tmp))
        source = REPO / "configs" / "plans" / "sequential-campaign.yaml"
        designed = designed_from(source, STATION, session, Path(tmp) / "designed-64.yaml")
        plans = {**PLANS, "designed for sim-64 (--from a measuring session)": designed}
        for name, path in plans.items():
            check = check_campaign(load_campaign(path, STATION))
            total_min = check.duration_s / 60
            print(f"  {name}: {total_min:.0f} min for {check.n_duts} DUTs = "
                  f"{total_min / check.n_duts:.2f} min per DUT")


def main() -> None:
    if "--campaign" in sys.argv:
        print(json.dumps(campaign_figures(int(sys.argv[sys.argv.index("--campaign") + 1]))))
        return
    reading_table(cfg.load_station(STATION))
    if "--skip-campaign" not in sys.argv:
        campaign_table()
    chamber_minutes()
    if "--skip-timing" not in sys.argv:
        timing_table()


if __name__ == "__main__":
    main()
