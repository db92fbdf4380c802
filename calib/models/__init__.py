"""The calibration models and their fits (T24 and its Gram solver, T36, P12, the scalar fit) and the registry
that lists them."""
