"""The covariance between the calibrations of a campaign's DUTs, written beside them: the coil matrix, the
reference magnetometer, the ambient and the other inputs every DUT of the run shares are one and the same
for all of them, so anyone combining DUTs (an array, a gradiometer) needs cov(theta_a, theta_b).

    collector = CrossCovariance()
    collector.add(dut, model, labels, shared)   # each DUT's fit (rig/analysis/dutfits.py)
    path = collector.write(session_path)         # <session stem>.cross-covariance.json
    cov = cross_covariance(path, "t24", "dut1", "dut2")     # (P_a, P_b), parameters in file order

The file (JSON) holds, per model, the parameter labels (the order of the calibration files' covariance)
and, per shared input, its covariance Sigma_q (Q,Q) once and each DUT's sensitivity J (P,Q) = d theta / d q
(calib.uncertainty.propagation; exact for T24, first order for the others):

    cov(theta_a, theta_b) = sum over shared inputs s of  J_a,s Sigma_s J_b,s^T        (a != b)

This factored form is exact and small (the full matrix of 64 T24 DUTs would hold 2.4 million numbers).
A DUT's own covariance, cov(theta_a, theta_a), is its calibration file's `uncertainty.covariance`, which
adds the inputs it does not share (its own noise, position, temperature, model error).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib.io.atomic import atomic_write
from rig.core.errors import DataError
from rig.core.paths import inside

FORMAT_NAME = "magrig-cross-covariance"


def cross_covariance_path(session_path: str | Path) -> Path:
    session_path = Path(session_path)
    return inside(session_path.parent, f"{session_path.name.removesuffix('.session')}.cross-covariance.json")


class CrossCovariance:
    """Collects the shared inputs' sensitivities of every DUT's budget, per model."""

    def __init__(self):
        self.models: dict[str, dict] = {}
        self.notes: list[str] = []

    def add(self, dut: str, model: str, labels: list[str], shared: list) -> None:
        """One DUT's fit: its parameter labels and its budget's shared inputs [(name, covariance,
        jacobian)] (rig/analysis/dutfits.py shared_inputs)."""
        if not labels:
            return
        entry = self.models.setdefault(model, {"parameters": list(labels), "shared": {}})
        for name, covariance, jacobian in shared:
            sigma = np.atleast_2d(np.asarray(covariance, float))
            kept = entry["shared"].setdefault(name, {"covariance": sigma, "jacobians": {}})
            if kept["covariance"].shape != sigma.shape or not np.allclose(kept["covariance"], sigma,
                                                                           rtol=1e-9, atol=0.0):
                self.notes.append(f"{model} {dut}: shared input {name!r} has another covariance "
                                  "than the first DUT's: left out of its cross-covariance")
                continue
            kept["jacobians"][dut] = jacobian

    def as_dict(self) -> dict:
        out = {"format": FORMAT_NAME, "format_version": 1,
               "formula": "cov(theta_a, theta_b) = sum_s J_a,s Sigma_s J_b,s^T over the shared inputs s",
               "notes": list(self.notes), "models": {}}
        for model, entry in self.models.items():
            out["models"][model] = {
                "parameters": entry["parameters"],
                "shared": {name: {"covariance": s["covariance"].tolist(),
                                  "jacobians": {dut: np.asarray(j, float).tolist()
                                                for dut, j in s["jacobians"].items()}}
                           for name, s in entry["shared"].items()}}
        return out

    def write(self, session_path: str | Path) -> Path | None:
        if not self.models:
            return None
        path = cross_covariance_path(session_path)
        try:
            with atomic_write(path) as f:
                json.dump(self.as_dict(), f)
        except OSError as err:
            raise DataError(f"{path}: cannot write the cross-covariance ({err.strerror or err})") from None
        return path


def cross_covariance(path: str | Path, model: str, dut_a: str, dut_b: str) -> np.ndarray:
    """(P_a, P_b): the covariance between two DUTs' parameters of `model` through their shared inputs."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as err:
        raise DataError(f"{path}: cannot read the cross-covariance ({err})") from None
    if data.get("format") != FORMAT_NAME:
        raise DataError(f"{path}: not a cross-covariance file (format {data.get('format')!r})")
    entry = data["models"].get(model)
    if entry is None:
        raise DataError(f"{path}: no model {model!r} (models: {', '.join(data['models'])})")
    size = len(entry["parameters"])
    out = np.zeros((size, size))
    for shared in entry["shared"].values():
        jac = shared["jacobians"]
        if dut_a in jac and dut_b in jac:
            out += np.asarray(jac[dut_a]) @ np.asarray(shared["covariance"]) @ np.asarray(jac[dut_b]).T
    return out
