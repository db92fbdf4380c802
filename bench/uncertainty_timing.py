"""Timings of the uncertainty (bench/uncertainty.py timing), and the demo's certificates (certificates).

timing: the demo plan (4 temperatures x 26 fields x 5 samples, its T24 and P12 fits) on
configs/stations/sim-64.yaml (64 DUTs) and on two of its DUTs, each `rig run` in a new process: its wall
time, the post-run fits' share (the session's own record of them), and the 64 / 2 ratio. Then every
budget of the 64-DUT session's DUTs with T24, P12 and the scalar model (bench/budget_timer.py:
RunInputs.budget, every DUT and model) in one process and in two. With
--before COMMIT the same runs are made with that commit's code (a copy from `git archive`), so the
figures before and after come from the same machine in the same hour.

certificates: the demo plan on configs/stations/sim-lab.yaml, and `rig certificate` for each DUT (HTML, its
DCC and, where a renderer is available, PDF): each one's time, its marks, and whether its DCC is valid
against DCC 3.1.2 (tests/data/dcc, where xmlschema is installed).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
STATION64 = REPO / "configs" / "stations" / "sim-64.yaml"
LAB = REPO / "configs" / "stations" / "sim-lab.yaml"
DEMO = REPO / "configs" / "plans" / "demo.yaml"
def _plan(folder: Path, station: Path) -> Path:
    data = yaml.safe_load(DEMO.read_text())
    data["station"] = str(station)
    path = folder / "plan.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _two_duts(folder: Path) -> Path:
    data = yaml.safe_load(STATION64.read_text())
    keep = [d["name"] for d in data["duts"] if d["type"] == "mmc5983ma"][:2]
    data["duts"] = [d for d in data["duts"] if d["name"] in keep]
    data["temperature_sensors"] = [s for s in data["temperature_sensors"] if s["beside"] in keep]
    path = folder / "sim-2.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _run(code: Path, station: Path, folder: Path, launcher: Path | None = None) -> tuple[float, Path]:
    """(wall s, session) of `rig run` of the demo in a new process with the code in `code` (`launcher`: a
    script that stands for `-m rig`, e.g. bench/free_physics.py)."""
    folder.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(code), "OPENBLAS_NUM_THREADS": "1"}
    start = time.perf_counter()
    rig = ["-m", "rig"] if launcher is None else [str(launcher)]
    proc = subprocess.run([sys.executable, *rig, "run", str(_plan(folder, station)), "--out",
                           str(folder), "--no-live"], cwd=code, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode not in (0, 3):
        raise RuntimeError(proc.stderr[-2000:])
    return wall, next(folder.glob("*.session"))


def _postrun_s(session: Path) -> float | None:
    """The post-run fits' wall time as the session recorded it (None: a session from before)."""
    from rig.session.reader import SessionReader

    with SessionReader(session) as reader:
        for e in reversed(reader.events()):
            m = re.search(r"post-run fits done: \d+ in ([0-9.]+) s", e.message)
            if m:
                return float(m.group(1))
    return None


def _budget_times(code: Path, session: Path) -> tuple[float, float]:
    """Every budget of the session with the code in `code` (bench/budget_timer.py, a new process each):
    seconds in one process and in two."""
    env = {**os.environ, "PYTHONPATH": str(code), "OPENBLAS_NUM_THREADS": "1"}
    out = []
    for jobs in (1, 2):
        proc = subprocess.run([sys.executable, str(REPO / "bench" / "budget_timer.py"), str(session),
                               "--jobs", str(jobs)], cwd=code, env=env, capture_output=True, text=True,
                              check=True)
        out.append(float(proc.stdout.split()[-1]))
    return out[0], out[1]


def _checkout(commit: str, out: Path) -> Path:
    target = out / f"code-{commit[:8]}"
    if not target.exists():
        target.mkdir(parents=True)
        archive = out / "code.tar"
        subprocess.run(["git", "archive", "-o", str(archive), commit], cwd=REPO, check=True)
        with tarfile.open(archive) as tar:
            tar.extractall(target, filter="data")
    return target


def timing(out: Path, before: str | None = None) -> None:
    versions = [("after", REPO)] + ([("before", _checkout(before, out))] if before else [])
    two = _two_duts(out)
    for label, code in versions:
        wall64, session64 = _run(code, STATION64, out / label / "64")
        wall2, session2 = _run(code, two, out / label / "2")
        one, both = _budget_times(code, session64)
        post64, post2 = _postrun_s(session64), _postrun_s(session2)
        posts = "" if post64 is None else f" (post-run fits {post64:.1f} s and {post2:.1f} s)"
        print(f"{label}: demo on 64 DUTs {wall64:.1f} s, on 2 DUTs {wall2:.1f} s{posts}: ratio "
              f"{wall64 / wall2:.2f}; every budget of the 64 DUTs (T24, P12, scalar): {one:.1f} s in one "
              f"process, {both:.1f} s in two")


def certificates(out: Path) -> None:
    wall, session = _run(REPO, LAB, out / "lab")
    from rig.session.reader import SessionReader

    with SessionReader(session) as reader:
        duts = reader.duts()
    for dut in duts:
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "rig", "certificate", str(session), "--dut", dut, "-o",
                               str(out / "certificates")], cwd=REPO, capture_output=True, text=True)
        took = time.perf_counter() - start
        print(proc.stdout.strip() or proc.stderr.strip())
        page = next((out / "certificates").glob(f"*.{dut}.certificate.html"), None)
        if page is not None:
            marks = re.findall(r'<p class="mark">([^<]+)</p>', page.read_text())
            print(f"  {dut}: {took:.1f} s; marks: {', '.join(marks) or 'none'}; DCC {_dcc_valid(page)}")
    print(f"demo on {LAB.name}: {wall:.1f} s; certificates in {out / 'certificates'}")


def _dcc_valid(page: Path) -> str:
    dcc = page.with_name(page.name.replace(".certificate.html", ".dcc.xml"))
    try:
        import xmlschema
    except ImportError:
        return "not validated (pip install xmlschema)"
    schema = xmlschema.XMLSchema(str(REPO / "tests" / "data" / "dcc" / "dcc.xsd"), allow="local")
    return "valid against DCC 3.1.2" if schema.is_valid(str(dcc.resolve())) else "INVALID"
