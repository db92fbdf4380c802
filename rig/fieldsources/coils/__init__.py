"""Three-axis coils: the station's `field_source: {kind: coils}` (config.py), the loops' field at each
position (geometry.py), what commissioning measures of them (commissioning.py) and the sources of their
reference field in a calibration's budget (budget.py)."""
