"""A calibration's uncertainty: the budget, exact linear propagation, linearisations, Monte Carlo refits, GUM
S1's adaptive procedure and the law's check, the field error at a reading."""
