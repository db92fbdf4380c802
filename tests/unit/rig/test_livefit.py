"""The live fits: solved when their figures are read, again after new samples, never per add."""

from __future__ import annotations

import numpy as np

from rig.analysis.livefit import LiveFit, LiveSummaries


def test_live_summaries_are_made_when_read_and_follow_new_samples():
    rng = np.random.default_rng(7)
    fits = {"a": LiveFit(25.0), "b": LiveFit(25.0)}
    summaries = LiveSummaries(fits)
    assert dict(summaries) == {"a": "no data yet", "b": "no data yet"}
    for temp_c in (0.0, 50.0):
        ref = rng.normal(0, 30_000, (40, 3))
        fits["a"].add(ref * 1.001 + rng.normal(0, 10, (40, 3)), np.full(40, temp_c), ref)
    assert summaries["a"].startswith("n=80: rms ") and fits["a"].rms_nt < 30
    fits["a"].add(np.zeros((5, 3)), np.full(5, 25.0), np.full((5, 3), 1e4))  # a bad point: rms grows
    assert summaries["a"].startswith("n=85: rms ") and fits["a"].rms_nt > 100
    summaries["b"] = "PASS " + summaries["b"]  # a verdict in front of the summary is kept as set
    assert summaries["b"] == "PASS no data yet" and len(summaries) == 2
