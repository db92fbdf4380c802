"""Calibration maths: pure numpy, arrays in, fitted models out. No I/O inside the solvers."""
