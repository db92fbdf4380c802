"""examples/apply_from_file.py reads nothing but the calibration file's stated keys (equation, reading, tau,
frame, indexing, params; tau_0_c where the equation subtracts it), imports nothing of magrig, and gives
what `rig apply` gives to 1e-9 for every model."""

from __future__ import annotations

import ast
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import calib
from calib import synthetic
from calib.io import calfile, csvio
from rig.cli import main

SCRIPT = Path(__file__).resolve().parents[3] / "examples" / "apply_from_file.py"


def _fitted(model: str, rng):
    if model in ("t24", "t36"):
        ds, _ = synthetic.t24_dataset(rng, samples_per_point=2)
        return calib.fit(ds, model)
    if model == "p12":
        ds, _ = synthetic.p12_dataset(rng, samples_per_point=2)
        return calib.fit(ds, model)
    ds, _ = synthetic.scalar_dataset(rng, n=300, temps_c=(0.0, 20.0, 40.0))
    return calib.fit(ds, "scalar", temperature_terms=True, temp_ref_c=17.5)  # its equation subtracts tau_0_c


def _field(path: Path) -> np.ndarray:
    with open(path) as f:
        return np.array([[float(r["bx"]), float(r["by"]), float(r["bz"])] for r in csv.DictReader(f)])


def test_the_script_imports_nothing_of_magrig():
    tree = ast.parse(SCRIPT.read_text())
    imported = {alias.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import)
                for alias in node.names}
    imported |= {node.module.split(".")[0] for node in ast.walk(tree)
                 if isinstance(node, ast.ImportFrom) and node.module}
    assert imported <= {"__future__", "argparse", "csv", "json", "math", "sys", "yaml"}


@pytest.mark.parametrize("model", ["t24", "t36", "p12", "scalar"])
def test_the_file_alone_reproduces_rig_apply(model, tmp_path, capsys):
    rng = np.random.default_rng({"t24": 11, "t36": 12, "p12": 13, "scalar": 14}[model])
    cal = _fitted(model, rng)
    assert model != "scalar" or "tau_0_c" in cal.equation_keys()["equation"]
    cal_path = tmp_path / ("cal.json" if model == "p12" else "cal.yaml")  # JSON files too
    calfile.save(cal, cal_path)
    h, t = rng.normal(0, 40_000, (40, 3)), rng.uniform(-30, 70, 40)
    data = tmp_path / "data.csv"
    csvio.write_csv(data, {"hx": h[:, 0], "hy": h[:, 1], "hz": h[:, 2], "temp": t})
    assert main(["apply", str(cal_path), str(data), "-o", str(tmp_path / "rig.csv")]) == 0
    capsys.readouterr()
    done = subprocess.run([sys.executable, str(SCRIPT), str(cal_path), str(data), "-o",
                           str(tmp_path / "own.csv")], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    applied, own = _field(tmp_path / "rig.csv"), _field(tmp_path / "own.csv")
    assert np.max(np.linalg.norm(own - applied, axis=1) / np.linalg.norm(applied, axis=1)) < 1e-9
    # a file that does not state its indexing is refused, never read some other way
    unstated = tmp_path / "no-indexing.yaml"
    unstated.write_text(yaml.safe_dump({**cal.to_dict(), "indexing": None}, sort_keys=False))
    refused = subprocess.run([sys.executable, str(SCRIPT), str(unstated), str(data), "-o",
                              str(tmp_path / "x.csv")], capture_output=True, text=True)
    assert refused.returncode != 0 and "indexing" in refused.stderr
