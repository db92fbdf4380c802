"""Commissioning maths: a coil set's matrix and ambient, a turntable's axes, from reference readings."""
