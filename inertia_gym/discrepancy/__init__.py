"""Discrepancy diagnosis: recordings I/O, replay and residuals, the physics catalogue, fit, report."""
