"""Statistics calib's fits and budgets share: distributions, Student's t coverage factors, robust weights, the
field directions taken, residual statistics."""
