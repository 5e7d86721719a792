"""Verdicts on a system: scenarios, the interface check, stress tests, plots, the pytest plugin."""
