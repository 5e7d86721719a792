"""abyss: a testbed for deep-sea ROV software.

One import namespace, mapped from the repository's top-level folders by the packaging, each
folder one concept, lowest first: what is small and generic (`abyss.common`), the robot and the
site as data (`abyss.description`), what stations say to each other (`abyss.interface`: keys,
messages, QoS, the fault table), time (`abyss.timing`), certificates and access rules
(`abyss.security`), the typed configuration (`abyss.config`), the session (`abyss.bus`); the
link emulator (`abyss.linkemu`), the octree stream (`abyss.scene`), the recording and ROS 2; the
system under test, `abyss.stations` (simulation, onboard, vessel, onshore); and the testbed
around them: `abyss.launch` (whole systems: `abyss up`), `abyss.validation` (scenarios,
campaigns, the robot check, stress tests, plots, the pytest plugin), `abyss.console` (the
operator's tools) and `abyss.cli` (the command line, which only parses arguments and calls
them). docs/architecture.md draws the rooms and what each may import."""
