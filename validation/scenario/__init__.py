"""Validation scenarios: TOML files with a system's configuration, timed events and
assertions (`spec.py`, read through the one typed reader with `fields.py`), the event kinds
(`events/`, registered in `EVENTS`) and the checks (`checks.py`, registered in `CHECKS`), run as
whole isolated systems in parallel (`runner.py`) and reported as JUnit XML and Markdown
(`report.py`)."""
