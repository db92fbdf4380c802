"""The walk of two everyday operations through the tree: the calls that cross from one room into another
(rig/ folders; calib and drivers each one room) from a direct caller of ours, the rooms entered, and the
climbs back up (such a call into a room of a higher tier: control that came back up through a callback or
an object handed down, rather than going one way), with the first steps of the walk's top level. Calls a
library makes (pydantic's validators, a thread's target) are not steps of ours and are not counted.

    python bench/walks.py [--repo PATH] [--session SESSION]

1. a session fit: `rig refit SESSION --dut mmc0 --model t24` (the demo's session; one is run when
   --session is not given);
2. the post-run pass of a run on a copy of that session: every model of the plan fitted for every DUT,
   each calibration's budget, and the plan's acceptance judged (postrun.fit_session, accept_session), with
   how often it opens a session file by path and estimates a DUT's thermal lag;
3. a station built: open_rig on configs/stations/sim.yaml, every device made safe, closed.

Each operation runs once untraced (imports and caches warm), then traced with sys.setprofile. --repo
measures another checkout (its own tier order, tests/unit/test_layers.py RIG_TIERS): run it with that
checkout first on PYTHONPATH, e.g. `PYTHONPATH=/tmp/old .venv/bin/python bench/walks.py --repo /tmp/old`.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import io
import shutil
import sys
import tempfile
import threading
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TOP_DEPTH = 3  # project frames deep: the walk's top level


def rig_tiers(repo: Path) -> tuple[str, ...]:
    """RIG_TIERS as the checkout's layer test states them."""
    tree = ast.parse((repo / "tests" / "unit" / "test_layers.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "RIG_TIERS":
            return tuple(ast.literal_eval(node.value))
    raise SystemExit(f"{repo}: no RIG_TIERS in tests/unit/test_layers.py")


class Rooms:
    def __init__(self, repo: Path):
        self.repo = repo.resolve()
        self.tier = {name: i for i, names in enumerate(rig_tiers(repo)) for name in names.split()}

    def of(self, filename: str) -> str | None:
        path = Path(filename)
        if not path.is_absolute() or not path.is_relative_to(self.repo):
            return None
        parts = path.relative_to(self.repo).parts
        if parts[0] == "rig" and len(parts) > 2:
            return f"rig/{parts[1]}"
        if parts[0] in ("calib", "drivers"):
            return parts[0]
        return None

    def tier_of(self, room: str) -> int:
        return self.tier.get(room.removeprefix("rig/"), -1)  # calib and drivers lie below rig


COUNTED = {"session opened by path": ("SessionReader.__init__", "reader.py"),
           "thermal lag estimated": ("estimate_lag", "lag.py")}


def traced(rooms: Rooms, operation, counts: Counter | None = None):
    """(every call that crosses rooms as (caller's room, callee's room), the modules entered, the walk's
    top level: the rooms entered by calls at most TOP_DEPTH project frames deep); `counts` gets the calls
    to each of COUNTED."""
    crossings: list[tuple[str, str]] = []
    modules: set[str] = set()
    top: list[str] = []
    lock = threading.Lock()

    def profile(frame, event, _arg):
        if event != "call":
            return
        room = rooms.of(frame.f_code.co_filename)
        if room is None:
            return
        if counts is not None:
            for what, (name, file) in COUNTED.items():
                if frame.f_code.co_qualname == name and frame.f_code.co_filename.endswith(file):
                    counts[what] += 1
        # the direct caller's room: a call that came through a library (a validator pydantic runs, a thread's
        # target) has none, and is not a step of ours
        caller = None if frame.f_back is None else rooms.of(frame.f_back.f_code.co_filename)
        depth, back = 0, frame.f_back
        while back is not None:  # how deep in project frames this call is
            depth += rooms.of(back.f_code.co_filename) is not None
            back = back.f_back
        with lock:
            modules.add(frame.f_code.co_filename)
            if caller is not None and caller != room:
                crossings.append((caller, room))
                if depth <= TOP_DEPTH and (not top or top[-1] != room):
                    top.append(room)

    operation()  # warm: imports, compiled kernels, caches
    threading.setprofile(profile)
    sys.setprofile(profile)
    try:
        operation()
    finally:
        sys.setprofile(None)
        threading.setprofile(None)
    return crossings, modules, top


def describe(name: str, rooms: Rooms, crossings, modules: set[str], top: list[str],
             counts: Counter | None = None) -> None:
    climbs = [(a, b) for a, b in crossings if rooms.tier_of(b) > rooms.tier_of(a)]
    entered = Counter(b for _, b in crossings)
    print(f"{name}: {len(crossings)} calls into another room ({len(entered)} rooms), {len(climbs)} climbs "
          f"back up, {len(modules)} modules")
    print("  rooms entered: " + ", ".join(f"{room} x{n}" for room, n in entered.most_common()))
    if climbs:
        print("  climbs: " + ", ".join(f"{a} -> {b} x{n}" for (a, b), n in Counter(climbs).most_common(5)))
    print("  top level: " + " -> ".join(top[:16]) + (" ..." if len(top) > 16 else ""))
    if counts is not None:
        print("  " + ", ".join(f"{what}: {counts[what]}" for what in COUNTED))


def demo_session(out: Path, repo: Path) -> Path:
    """The demo plan run with acceptance limits (a held-out RMS and a thermal lag to judge), so that the
    post-run pass judges every DUT."""
    import yaml

    from rig.cli import main as rig_main

    plan = yaml.safe_load((repo / "configs" / "plans" / "demo.yaml").read_text())
    plan["station"] = str(repo / "configs" / "stations" / "sim.yaml")
    plan["acceptance"] = {"max_heldout_rms_nt": 1000.0, "max_lag_s": 3600.0}
    path = out / "walk.yaml"
    path.write_text(yaml.safe_dump(plan))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        rig_main(["run", str(path), "--out", str(out), "--no-live"])
    return next(out.glob("*.session"))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repo", type=Path, default=REPO)
    parser.add_argument("--session", type=Path,
                        help="a session whose plan has acceptance limits (default: the demo run with some)")
    parser.add_argument("--keep", type=Path, help="a folder to keep the demo's session in (for --session)")
    args = parser.parse_args(argv)
    repo = args.repo.resolve()
    rooms = Rooms(repo)
    from rig.cli import main as rig_main

    with tempfile.TemporaryDirectory() as tmp:
        session = args.session or demo_session(args.keep or Path(tmp), repo)
        out = Path(tmp) / "walk.t24.yaml"

        def session_fit():
            out.unlink(missing_ok=True)
            with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
                rig_main(["refit", str(session), "--dut", "mmc0", "--model", "t24", "-o", str(out)])

        describe("session fit", rooms, *traced(rooms, session_fit))

        from rig.analysis import postrun
        from rig.reference import chain_record
        from rig.session.reader import SessionReader
        from rig.session.writer import Session

        with SessionReader(session) as reader:  # the plan and station the session recorded, as a run has them
            plan, station = chain_record.recorded_plan_and_station(
                session, reader.info(), reader.snapshot(chain_record.SNAPSHOT))
        copy = Path(tmp) / "copy.session"
        counts: Counter = Counter()

        def post_run():
            shutil.copyfile(session, copy)
            for name in copy.parent.glob(copy.name.removesuffix(".session") + ".*.yaml"):
                name.unlink()
            with Session.open(copy) as opened:
                fits = postrun.fit_session(opened, plan, station)
                postrun.accept_session(opened, plan, station, fits, {})

        describe("post-run pass", rooms, *traced(rooms, post_run, counts), counts)

    from drivers.base import make_all_safe
    from rig.config import load_station

    station = load_station(repo / "configs" / "stations" / "sim.yaml")

    def station_build():
        from rig.devices.build import open_rig

        rig = open_rig(station, None, None)
        try:
            make_all_safe(rig.devices())
        finally:
            rig.close()

    describe("station built", rooms, *traced(rooms, station_build))


if __name__ == "__main__":
    main()
