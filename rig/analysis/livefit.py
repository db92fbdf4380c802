"""The streaming T24 fit of one DUT, updated after every point: the live display's and the cockpit's
running residual. Both feed it the samples of each stored point and never refit from scratch.

    fit = LiveFit(temp_ref_c=25.0)
    fit.add(h_nt, temp_c, ref_nt)       # (n, 3), (n,), (n, 3)
    fit.figures() -> {"n": 520, "rms_nt": 17.4, "identifiable": True, "largest_se": {...}}
    fit.summary() -> "n=520: rms 17.4 nT, largest se: b 0.61 nT, S 12 ppm, K 0.42 ppm/C"
"""

from __future__ import annotations

import numpy as np

from rig.core.errors import ERRORS


class LiveFit:
    def __init__(self, temp_ref_c: float):
        from calib.gram import GramAccumulator

        self.acc = GramAccumulator(temp_ref_c)
        self.rms_nt: float | None = None  # of the last solve (the live view shows the worst DUTs first)

    def add(self, h_nt, temp_c, ref_nt) -> None:
        if len(h_nt):
            self.acc.add(h_nt, temp_c, ref_nt)

    def figures(self) -> dict:
        """Samples so far and, once the T24 parameters can be identified, the fit's residual RMS (nT) and
        its largest standard errors (b in nT, S in ppm, K in ppm/degC)."""
        out: dict = {"n": int(self.acc.n), "rms_nt": None, "identifiable": False, "largest_se": None}
        if self.acc.n == 0 or self.acc.identifiability() is not None:
            return out
        try:
            cal = self.acc.solve()
        except ERRORS:
            return out
        se = cal.std_errors
        self.rms_nt = float(cal.stats["rms_after_nt"])
        out.update(rms_nt=self.rms_nt, identifiable=True,
                   largest_se={"b_nt": float(np.max(se["b_nt"])), "S_ppm": float(np.max(se["S"]) * 1e6),
                               "K_ppm_per_c": float(np.max(se["K"]) * 1e6)})
        return out

    def summary(self) -> str:
        f = self.figures()
        if f["n"] == 0:
            return "no data yet"
        if not f["identifiable"]:
            return f"n={f['n']}: not yet identifiable"
        se = f["largest_se"]
        return (f"n={f['n']}: rms {f['rms_nt']:.1f} nT, largest se: b {se['b_nt']:.2f} nT, "
                f"S {se['S_ppm']:.0f} ppm, K {se['K_ppm_per_c']:.2f} ppm/C")
