"""A DUT's uncertainty budget on the rig's side: the run's inputs (reference chain, temperatures, ambient),
what the model leaves out (model checks' terms, misfit, offset wander) and the thermal hysteresis corrected
before the fit; calib/uncertainty/ does the maths."""
