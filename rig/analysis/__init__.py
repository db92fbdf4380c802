"""After (and during) a run: the post-run fit of every DUT with its budget, the lag-corrected fit of moving
schedules, the live fit, held-out evaluation and the acceptance verdicts."""
