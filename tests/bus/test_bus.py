"""A typed subscription: `bus.subscribe(station, topic, Heartbeat)` hands out an inbox of what the
key carries, and a class that is not what `keys.KEYS` says the key carries, or no class at all, is
refused at once."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from abyss.bus.session import Bus, open_session, zenoh_config
from abyss.common.errors import ConfigError
from abyss.common.ports import free_port
from abyss.interface.messages import Heartbeat, Telemetry


@pytest.fixture
def buses() -> Iterator[tuple[Bus, Bus]]:
    session = open_session(zenoh_config([f"tcp/127.0.0.1:{free_port()}"]), "test")
    vessel, onboard = Bus("typed", "vessel", session), Bus("typed", "onboard", session)
    yield vessel, onboard
    onboard.close()
    vessel.close()
    session.close()


def test_a_typed_inbox_gets_what_its_key_carries_and_another_class_is_refused(buses: tuple[Bus, Bus]) -> None:
    vessel, onboard = buses
    beats = onboard.subscribe("vessel", "heartbeat", Heartbeat, maxlen=4)
    untyped = onboard.subscribe("vessel", "heartbeat", Heartbeat, maxlen=4)  # a second inbox on the key
    with pytest.raises(ConfigError, match="carries Heartbeat, not Telemetry"):
        onboard.subscribe("vessel", "heartbeat", Telemetry)
    deadline = time.monotonic() + 5.0
    while beats.latest() is None and time.monotonic() < deadline:
        vessel.publish("heartbeat", Heartbeat(shore_silence_s=1.5, shore_heard=False))
        time.sleep(0.05)
    got = beats.latest()
    assert got is not None and got.message.shore_silence_s == 1.5 and not got.message.shore_heard
    assert isinstance(got.message, Heartbeat) and got.key == "abyss/typed/vessel/heartbeat"
    assert untyped.latest() is not None and onboard.rejected == {}


def test_a_subscription_without_the_class_its_key_carries_is_refused_naming_key_and_classes(
    buses: tuple[Bus, Bus],
) -> None:
    _, onboard = buses
    with pytest.raises(ConfigError) as wrong:
        onboard.subscribe("vessel", "heartbeat", Telemetry)
    assert str(wrong.value) == "abyss/typed/vessel/heartbeat: carries Heartbeat, not Telemetry"
    with pytest.raises(ConfigError) as named:  # the name, as the untyped form took it
        onboard.subscribe("vessel", "heartbeat", "Heartbeat")  # type: ignore[arg-type]
    assert str(named.value) == (
        "abyss/typed/vessel/heartbeat: subscribed with 'Heartbeat', not a message class (Heartbeat)"
    )
    with pytest.raises(ConfigError, match="abyss/typed/onboard/control: subscribed with 'SimTime', not a"):
        onboard.subscribe_key("abyss/typed/onboard/control", "SimTime")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'message'"):
        onboard.subscribe("vessel", "heartbeat", maxlen=4)  # type: ignore[call-arg]
    assert onboard.data_keys() == set()  # nothing half subscribed
