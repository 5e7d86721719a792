"""The contract node (rosnode.py) for a few seconds under whatever zenoh-python is first on the
path: run with a Zenoh release rmw_zenoh bundles on PYTHONPATH (test_ros2_gateway's
cross-version test). It finds the gateway's node in the ROS graph (liveliness), flies with the
waypoint pilot (odometry, the clock and the Path in, TwistStamped out), takes /tf_static from the
gateway's cache as a late subscriber (transient local) and prints what it saw as one JSON line.

    PYTHONPATH=DIR_WITH_ZENOH:tests/e2e python tests/e2e/rosnode_versions.py ENDPOINT SECONDS"""

import importlib.metadata
import json
import sys
import threading
import time

import zenoh
import zenoh.ext
from rosnode import RosNode, TFMessage, WaypointPilot, data_key


def main() -> None:
    endpoint, seconds = sys.argv[1], float(sys.argv[2])
    node = RosNode(endpoint, name="team_onboard_versions")
    deadline, gateway = time.monotonic() + 20.0, []
    while not gateway and time.monotonic() < deadline:
        gateway = [t for t in node.graph() if t.node == "abyss_onboard_gateway"]
    static: list[TFMessage] = []  # transient local: the gateway's cache to a subscriber that comes late
    late = (  # zenoh-python has advanced subscribers from 1.5 on (zenoh-c, as rmw_zenoh uses it, before)
        zenoh.ext.declare_advanced_subscriber(
            node.session,
            data_key(0, "/tf_static", TFMessage),
            lambda s: static.append(TFMessage.deserialize(s.payload.to_bytes())),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
        )
        if hasattr(zenoh.ext, "declare_advanced_subscriber")
        else None
    )
    pilot, stop = WaypointPilot(node), threading.Event()
    flying = threading.Thread(target=pilot.fly, args=(stop,), daemon=True)
    flying.start()
    time.sleep(seconds)
    stop.set()
    flying.join(timeout=5)
    # the gateway's endpoints as the graph holds them now: the first look above ended on the first
    # of its liveliness tokens to arrive, however many more were on their way (CI saw 1 of 4)
    gateway = [t for t in node.graph() if t.node == "abyss_onboard_gateway"]
    if late is not None:
        late.undeclare()
    node.close()
    print(
        json.dumps(
            {
                "zenoh": importlib.metadata.version("eclipse-zenoh"),
                "zenoh_file": zenoh.__file__,
                "gateway_endpoints": len(gateway),
                "odometry": len(pilot.flight.odometry),
                "clock": len(pilot.flight.clock_s),
                "waypoints": len(pilot.flight.waypoints),
                "commands": pilot.flight.commands,
                "tf_static": len(static) if late is not None else None,
            }
        )
    )


if __name__ == "__main__":
    main()
