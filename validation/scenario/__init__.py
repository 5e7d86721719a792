"""Validation scenarios: TOML files with a system's configuration, timed events and
assertions (`spec.py`), run as whole isolated systems in parallel (`runner.py`), judged
(`checks.py`) and reported as JUnit XML and Markdown (`report.py`)."""
