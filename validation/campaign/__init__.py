"""Campaigns: the scenario library times seeds times variations, run as a whole (on Ray) and
judged per scenario and variant with a statistically sound pass rate. A campaign file
(`spec.py`) becomes a plan of runs, each with an id that hashes what makes it (`plan.py`); the
results are stored as they arrive (`store.py`) and reported as Markdown, JSON, JUnit and plots
(`stats.py`, `figures.py`, `report.py`)."""
