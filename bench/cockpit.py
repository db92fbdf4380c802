"""The cockpit's cost to a campaign and how fast it shows a point (issue 17):

- campaign wall time with the cockpit's live page open against without: the demo plan on the simulated
  station (run_campaign, as `rig run` does), in pairs, alternating which goes first; `rig serve` runs in
  its own process and a headless Chromium keeps the campaign's live page open. Ratio of the medians
  (goal <= 1.05);
- push latency: for every point committed while the page was open, the wall time from the point's commit
  (the campaign's Checkpoint, right after its transaction) to the page receiving it (the page script's
  `window.cockpit.pointSeen`); median, 95th percentile and maximum (goal <= 2 s);
- the CPU time the cockpit took meanwhile (the `rig serve` process and the browser's processes, from
  /proc), against the campaign's own: on a machine shared with other work the wall-time ratio moves with
  their load, the CPU seconds say what the cockpit itself asked for.

    python bench/cockpit.py [--pairs 5] [--plan configs/plans/demo.yaml] [--station PATH]

Needs Chromium (/usr/bin/chromium, or $MAGRIG_CHROMIUM) and the playwright package (the test extra).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from rig.config.loading import load_campaign  # noqa: E402
from rig.run.campaign import run_campaign  # noqa: E402
from tests.system import browser  # noqa: E402

TICKS_S = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of one process (0 once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / TICKS_S


def descendants(root: int) -> set[int]:
    """Every process below `root` (the `rig serve` process, the browser and its helpers)."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
                parents[int(entry)] = int(stat.rsplit(")", 1)[1].split()[1])
            except OSError:
                continue
    found, grew = set(), True
    while grew:
        new = {p for p, parent in parents.items() if (parent == root or parent in found) and p not in found}
        found |= new
        grew = bool(new)
    return found


def run(campaign, session: Path, page=None, url: str | None = None) -> dict:
    """One campaign in a thread of this process (the page is driven from the main thread meanwhile)."""
    commits: dict[str, float] = {}
    box: dict = {}
    helpers = descendants(os.getpid())  # the server and the browser, not this process
    helpers_cpu0, own_cpu0 = sum(cpu_s(p) for p in helpers), time.process_time()

    def display(status, runner):
        runner.on_point.append(lambda point_id: commits.setdefault(point_id, time.time()))

    def work():
        box["outcome"] = run_campaign(campaign=campaign, session_path=session, display_factory=display)

    thread = threading.Thread(target=work)
    thread.start()
    seen, first_ms = {}, None
    if page is not None:
        while not session.exists() and thread.is_alive():
            time.sleep(0.01)
        page.goto(f"{url}/s/0/{session.name}/live")
        thread.join()
        n_points = box["outcome"].result.points_done
        end = time.monotonic() + 10  # the last points may still be on their way
        count = "Object.keys(window.cockpit.pointSeen).length"
        while time.monotonic() < end and page.evaluate(count) < n_points:
            time.sleep(0.05)
        seen = page.evaluate("window.cockpit.pointSeen")
        first_ms = page.evaluate("window.cockpit.firstMessageAt")
        page.goto("about:blank")
    thread.join()
    helpers_cpu = sum(cpu_s(p) for p in helpers) - helpers_cpu0
    own_cpu = time.process_time() - own_cpu0  # the campaign, its simulators and this process's idle rest
    outcome = box["outcome"]
    assert outcome.result.status == "completed", outcome.result.reason
    latencies = [(seen[p] / 1e3 - t, p) for p, t in commits.items()
                 if p in seen and t * 1e3 > first_ms]  # points that came after the page's first message
    return {"wall_s": outcome.wall_s, "latencies_s": latencies, "points": outcome.result.points_done,
            "cockpit_cpu_s": helpers_cpu, "campaign_cpu_s": own_cpu}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--plan", default=str(REPO / "configs/plans/demo.yaml"))
    parser.add_argument("--station", default=None)
    args = parser.parse_args()
    if (why := browser.missing()) is not None:
        sys.exit(f"cannot run: {why}")
    campaign = load_campaign(args.plan, args.station)
    with tempfile.TemporaryDirectory(prefix="bench-cockpit-") as tmp:
        folder = Path(tmp) / "sessions"
        folder.mkdir()
        runs = iter(range(10_000))
        with browser.cockpit(str(folder)) as url, browser.headless_page() as (page, errors):
            run(campaign, folder / f"warm-{next(runs)}.session")  # compiled fits cached, files warm
            without, with_page, latencies, ratios, cpu = [], [], [], [], []
            for pair in range(args.pairs):
                order = (False, True) if pair % 2 == 0 else (True, False)
                walls = {}
                for open_page in order:
                    r = run(campaign, folder / f"run-{next(runs)}.session", page if open_page else None, url)
                    walls[open_page] = r["wall_s"]
                    (with_page if open_page else without).append(r["wall_s"])
                    if open_page:
                        latencies += r["latencies_s"]
                        cpu.append((r["cockpit_cpu_s"], r["campaign_cpu_s"], r["wall_s"]))
                    print(f"  pair {pair + 1}: {'with' if open_page else 'without'} the page: "
                          f"{r['wall_s']:.2f} s", flush=True)
                ratios.append(walls[True] / walls[False])
            if errors:
                print(f"page errors: {errors}")
    ratio = float(np.median(with_page) / np.median(without))
    cockpit_cpu, campaign_cpu, wall = (float(np.median([c[i] for c in cpu])) for i in range(3))
    lat = np.array([x for x, _ in latencies])
    worst = sorted(latencies, reverse=True)[:3]
    print(f"campaign wall time ({Path(args.plan).name}, {r['points']} points, median of {args.pairs}): "
          f"without the cockpit {np.median(without):.2f} s, with its live page open "
          f"{np.median(with_page):.2f} s: ratio {ratio:.3f} (goal <= 1.05); pair by pair "
          f"{', '.join(f'{x:.3f}' for x in ratios)}")
    print(f"cockpit CPU during a campaign with the page open (median): {cockpit_cpu:.2f} s (server and "
          f"browser) against the campaign's {campaign_cpu:.2f} s, over {wall:.1f} s of wall time: "
          f"{cockpit_cpu / wall:.1%} of one core")
    print(f"push latency, point commit -> page, {lat.size} points: median {np.median(lat):.3f} s, "
          f"p95 {np.percentile(lat, 95):.3f} s, max {lat.max():.3f} s (goal <= 2 s); slowest: "
          + ", ".join(f"{p} {x:.2f} s" for x, p in worst))


if __name__ == "__main__":
    main()
