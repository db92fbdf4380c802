"""The simulated bench: a station's `sim:` made into one world (world.py) and a simulator for every device
whose transport is `{kind: sim}` (bench.py). The only part of rig/ that imports drivers.sim or reads `sim:`
(rig/config/ states it)."""
