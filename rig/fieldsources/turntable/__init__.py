"""A two-axis turntable in the site's field: the station's `field_source: {kind: turntable}` (config.py),
what commissioning measures of its axes (commissioning.py) and the sources of its reference field in a
calibration's budget (budget.py)."""
