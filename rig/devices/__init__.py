"""The rig as devices: built from a station on real transports (build.py, links.py) or on the simulated bench
(bench.py, the only reader of the station's `sim:` and of drivers.sim), interleaved reads, and the bus
scan."""
