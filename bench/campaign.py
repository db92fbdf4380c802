"""Campaign figures on the simulated station (every device on its real protocol, simulated time):

- wall time of the demo plan, and of the full campaign (8 temperatures x 48 fields x 50 samples x 2 DUTs);
- the engine's own overhead per point: wall time outside device I/O (driver calls, which include the
  simulators' real socket / pty round trips) and outside simulated waits, split into the session store's
  writes and the rest (engine, step generators, reference field, live fit).

    python bench/campaign.py [--skip-full]
"""

from __future__ import annotations

import functools
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rig.config.loading import load_campaign  # noqa: E402
from rig.engine.executor import Engine  # noqa: E402
from rig.run.campaign import run_campaign  # noqa: E402
from rig.session.writer import Session  # noqa: E402
from tests.system.campaign_helpers import SIM_STATION  # noqa: E402

DEVICE_METHODS = ("read", "set", "set_ramp_rate", "wait_settled", "safe_state")
STORE_METHODS = ("record_point", "log_event", "record_snapshot", "record_fit", "finish")


class Timers:
    def __init__(self):
        self.seconds: dict[str, float] = {}
        self.depth: dict[str, int] = {}

    def wrap(self, obj, name: str, bucket: str) -> None:
        fn = getattr(obj, name)

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if self.depth.get(bucket):  # a timed call inside another (wait_settled -> read): count once
                return fn(*args, **kwargs)
            self.depth[bucket] = 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.depth[bucket] = 0
                self.seconds[bucket] = self.seconds.get(bucket, 0.0) + time.perf_counter() - t0

        setattr(obj, name, timed)

    def instrument_rig(self, rig) -> None:
        for dev in rig.devices():
            for name in DEVICE_METHODS:
                if hasattr(dev, name):
                    self.wrap(dev, name, "device I/O")


def run(plan: Path, station: Path, out: Path, name: str, timers: Timers | None = None):
    campaign = load_campaign(plan, station)
    t0 = time.perf_counter()
    outcome = run_campaign(campaign=campaign, session_path=out / f"{name}.session",
                           on_rig=timers.instrument_rig if timers else None)
    wall = time.perf_counter() - t0
    assert outcome.result.status == "completed", outcome.result
    return outcome, wall


def main() -> None:
    skip_full = "--skip-full" in sys.argv
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        station = SIM_STATION

        timers = Timers()
        originals = {m: getattr(Session, m) for m in STORE_METHODS}
        original_run = Engine.run
        for m in STORE_METHODS:
            timers.wrap(Session, m, "session store")
        in_run: dict[str, float] = {}

        def run_and_measure(self, *args, **kwargs):  # the counters inside Engine.run only
            before = dict(timers.seconds)
            t0 = time.perf_counter()
            result = original_run(self, *args, **kwargs)
            in_run["run"] = time.perf_counter() - t0
            for key, value in timers.seconds.items():
                in_run[key] = value - before.get(key, 0.0)
            return result

        Engine.run = run_and_measure
        try:
            outcome, wall = run(REPO / "configs/plans/demo.yaml", station, out, "demo", timers)
        finally:
            for m, fn in originals.items():
                setattr(Session, m, fn)
            Engine.run = original_run
        points = outcome.result.points_done
        io_s, store_s = in_run.get("device I/O", 0.0), in_run.get("session store", 0.0)
        other_s = in_run["run"] - io_s - store_s
        print(f"demo: {points} points x 10 samples x 2 DUTs: wall {wall:.1f} s (start-up, fits and "
              f"calibration files included; the engine's run itself {in_run['run']:.1f} s)")
        print(f"  per point inside the run: device I/O {1e3 * io_s / points:.1f} ms, session store "
              f"{1e3 * store_s / points:.2f} ms, engine overhead (engine, steps, reference field, live fit, "
              f"settling logic) {1e3 * other_s / points:.2f} ms")

        if not skip_full:
            outcome, wall = run(REPO / "configs/plans/full-campaign.yaml", station, out, "full")
            info = Session.open(outcome.session_path).info()
            sim_h = (info["ended"] - info["started"]) / 3600
            print(f"full campaign: {outcome.result.points_done} points x 50 samples x 2 DUTs: wall "
                  f"{wall:.1f} s for {sim_h:.1f} h of simulated chamber time")
            for f in outcome.fits:
                rms = f.get("rms_nt")
                print(f"  {f['dut']} {f['model']}: rms {rms:.1f} nT" if rms is not None
                      else f"  {f['dut']} {f['model']}: {f.get('error')}")


if __name__ == "__main__":
    main()
