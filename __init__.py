"""abyss: a testbed for deep-sea ROV software.

One import namespace, mapped from the repository's top-level folders by the packaging:
the system under test, `abyss.stations` (simulation, onboard, vessel, onshore, and the
runtime that hosts one), what the stations share, `abyss.common` and the link emulator
`abyss.linkemu`; and the testbed around them: `abyss.launch` (whole systems: `abyss up`),
`abyss.validation` (scenarios, interface checks, stress tests, plots, the pytest plugin),
`abyss.console` (the operator's tools: op, teleop, replay) and `abyss.cli` (the command line,
which only parses arguments and calls them)."""
