"""Pick an offscreen GL backend before any test imports MuJoCo's rendering; run the whole-system
tests last, and start what a test module asks to begin early (its `begin()`: UML's boot) as
collection ends, so that it runs beside the unit tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

from abyss.stations.simulation.rendering import choose_gl_backend

# property tests judge results, not time: on this loaded 2-core machine an example's first run can
# pause for a GC or a neighbour's burst (292 ms against hypothesis's 200 ms deadline in CI)
settings.register_profile("abyss", deadline=None)
settings.load_profile("abyss")

choose_gl_backend()
E2E = Path(__file__).parent / "e2e"


def pytest_itemcollected(item: pytest.Item) -> None:
    """Everything under tests/e2e starts whole systems: the folder is the tier (`-m "not e2e"`)."""
    if E2E in item.path.parents:
        item.add_marker(pytest.mark.e2e)


@pytest.hookimpl(trylast=True)  # after -m and -k have deselected
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("e2e") is not None)  # stable: otherwise as found
    begun: set[object] = set()
    for item in items:
        module = getattr(item, "module", None)
        begin = getattr(module, "begin", None)
        if callable(begin) and module not in begun:
            begun.add(module)
            begin()
