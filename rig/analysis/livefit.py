"""The streaming T24 fit of one DUT, updated after every point: the live display's and the cockpit's
running residual. Both feed it the samples of each stored point and never refit from scratch.

    fit = LiveFit(temp_ref_c=25.0)
    fit.add(h_nt, temp_c, ref_nt)       # (n, 3), (n,), (n, 3)
    fit.figures() -> {"n": 520, "rms_nt": 17.4, "identifiable": True, "largest_se": {...}}
    fit.summary() -> "n=520: rms 17.4 nT, largest se: b 0.61 nT, S 12 ppm, K 0.42 ppm/C"
    summaries = LiveSummaries({"dut1": fit})   # {DUT: summary}, each made when read

A fit is solved when its figures are first asked for after new samples, not on every add: a run whose
live view nobody watches (`--no-live`, or the DUTs beyond the view's rows) solves none until the end.
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping

import numpy as np

from rig.core.errors import ERRORS


class LiveFit:
    def __init__(self, temp_ref_c: float):
        from calib.models.gram import GramAccumulator

        self.acc = GramAccumulator(temp_ref_c)
        self._figures: dict | None = None
        self._figures_n = -1  # the sample count they are of

    def add(self, h_nt, temp_c, ref_nt) -> None:
        if len(h_nt):
            self.acc.add(h_nt, temp_c, ref_nt)

    @property
    def rms_nt(self) -> float | None:
        """The residual RMS of the samples so far (None until identifiable): the live view shows the worst
        DUTs first."""
        return self.figures()["rms_nt"]

    def figures(self) -> dict:
        """Samples so far and, once the T24 parameters can be identified, the fit's residual RMS (nT) and
        its largest standard errors (b in nT, S in ppm, K in ppm/degC)."""
        if self._figures is None or self._figures_n != self.acc.n:
            self._figures, self._figures_n = self._solve(), self.acc.n
        return dict(self._figures)

    def _solve(self) -> dict:
        out: dict = {"n": int(self.acc.n), "rms_nt": None, "identifiable": False, "largest_se": None}
        if self.acc.n == 0 or self.acc.identifiability() is not None:
            return out
        try:
            cal = self.acc.solve()
        except ERRORS:
            return out
        se = cal.std_errors
        out.update(rms_nt=float(cal.stats["rms_after_nt"]), identifiable=True,
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


class LiveSummaries(MutableMapping):
    """{DUT: its live fit's summary()}, made when read; a text set here (an acceptance verdict in front of
    the summary) is kept as set."""

    def __init__(self, fits: dict[str, LiveFit]):
        self.fits = fits
        self.texts: dict[str, str] = {}

    def __getitem__(self, dut: str) -> str:
        return self.texts[dut] if dut in self.texts else self.fits[dut].summary()

    def __setitem__(self, dut: str, text: str) -> None:
        self.texts[dut] = text

    def __delitem__(self, dut: str) -> None:
        del self.texts[dut]

    def __iter__(self) -> Iterator[str]:
        return iter(self.fits)

    def __len__(self) -> int:
        return len(self.fits)
