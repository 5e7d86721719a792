"""A station's links on the netem shaper, for the UML test (test_netem_uml.py): the vessel's
StationLinks as a station makes them (real Zenoh, `--link` MODE), its tether and satellite
routed to two neighbours over their own interfaces, until the file STOP appears. It prints the
link mode that was taken; `abyss link set` and `show` reach it on tcp/127.0.0.1:PORT.

    python netem_links.py MODE PORT TETHER_PEER SATELLITE_PEER STOP
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

from abyss.bus.session import open_session, zenoh_config
from abyss.config.linkprofile import profile
from abyss.linkemu.control import StationLinks


def main(mode: str, port: str, tether_peer: str, satellite_peer: str, stop: str) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    session = open_session(zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), "netem_links")
    links = StationLinks(
        session,
        "uml",
        "vessel",
        {"tether": profile("tether"), "satellite": profile("satellite")},
        lambda key, payload: None,
        link_mode=mode,
        peers={"tether": tether_peer, "satellite": satellite_peer},
    )
    print(f"link mode {links.mode}", flush=True)
    while not Path(stop).exists():
        time.sleep(0.2)
    links.close()
    session.close()
    print("closed", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
