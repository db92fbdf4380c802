"""magrig: runs the calibration rig (config, plan, engine, store, report, CLI)."""

__version__ = "0.1.0"
