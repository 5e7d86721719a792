"""The vessel's cores without Zenoh, the network between them and shore being linkemu's `Link`
on explicit times, out of the cores' sight (as under `--link netem` or on a real link: the
station's own egress passes everything through). The scene stream must still pace itself to
the link, from shore's acknowledgements alone."""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pinocchio as pin
import pytest

from abyss.common.geometry import rotation_of
from abyss.config.linkprofile import profile
from abyss.config.stations import VesselConfig
from abyss.description.site import site_at
from abyss.interface.messages import (
    CommandAck,
    Heartbeat,
    Intervention,
    InterventionGoal,
    OperatorMode,
    RecognisedObjects,
    SceneAck,
    SceneUpdate,
    Telemetry,
    encode,
)
from abyss.linkemu.link import Link, Offer
from abyss.scene.model import SceneModel
from abyss.scene.pacing import ScenePacer
from abyss.scene.receiver import SceneReceiver
from abyss.scene.stream import SceneStream
from abyss.stations.vessel.core import Perception, Relay, RelayInputs
from abyss.stations.vessel.recognition import PanelTracker, PartAngle, Pose
from abyss.validation.stress import sample_telemetry

panel = site_at("").panel  # the shipped site's

STEP_S = 0.01


def seabed(rng: np.random.Generator, n: int = 4000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rough patch of seabed seen from 3 m above: points, colours, sensor origin."""
    xy = rng.uniform(-3.0, 3.0, (n, 2))
    points = np.c_[xy, 0.3 * np.sin(xy[:, 0] * 2.0) + rng.normal(0, 0.05, n)]
    colors = rng.integers(0, 255, (n, 3), dtype=np.uint8)
    return points, colors, np.array([0.0, 0.0, 3.0])


def fly(
    link_name: str, seconds: float, first_guess_bps: float, transport: str = "tcp", seed: int = 0
) -> dict[str, float]:
    """The vessel's scene stream to a shore that acknowledges each update, over `link_name` both
    ways, with telemetry beside it; what the stream learnt and what the link carried."""
    rng = np.random.default_rng(seed)
    down = profile(link_name).with_fields(  # the rate, the delay and the jitter; no loss
        {"loss": "0%", "corrupt": "0%", "loss_model": "bernoulli", "transport": transport}
    )
    to_shore, to_vessel = Link(down, np.random.default_rng(seed)), Link(down, np.random.default_rng(seed + 1))
    cfg = dataclasses.replace(VesselConfig(), satellite_capacity_bps=first_guess_bps)
    model = SceneModel(0.1, 8.0, cfg.scene_update_bytes)
    stream, receiver = SceneStream(cfg, model), SceneReceiver()
    most_in_flight, telemetry_delay_s, service = 0, [], [0.0, 0.0]  # bytes, seconds the link took
    for step in range(int(seconds / STEP_S)):
        now_s = step * STEP_S
        if step % 100 == 0:  # a new cloud every second
            model.insert(*seabed(rng))
        if step % 50 == 0:
            to_shore.offer(now_s, encode(sample_telemetry(), 0, now_s), tag="telemetry")
        acks = [d.tag for d in to_vessel.advance(now_s)]
        out = stream.step(now_s, now_s, [SceneAck(seq) for seq in acks], False, None)
        for topic, message in out.messages:
            assert topic == "scene" and isinstance(message, SceneUpdate)
            payload = encode(message, message.scene_seq, now_s)
            assert to_shore.offer(now_s, payload, block=True, tag=message) is Offer.ACCEPTED
        most_in_flight = max(most_in_flight, len(stream.pacer.in_flight))
        for d in to_shore.advance(now_s):
            if d.tag == "telemetry":
                telemetry_delay_s.append(d.delivered_s - d.offered_s)
            else:
                service[0] += len(d.payload)
                service[1] += d.delivered_s - d.offered_s - down.delay_s
                receiver.apply(d.tag)
                ack = SceneAck(d.tag.scene_seq)
                to_vessel.offer(now_s, encode(ack, 0, now_s), tag=ack.scene_seq)
    return {
        "capacity_bps": stream.pacer.capacity_bps,
        "rtt0_s": stream.pacer.rtt0_s,
        "most_in_flight": most_in_flight,
        "acked": stream.pacer.acked,
        "applied": receiver.applied,
        "telemetry_p95_s": float(np.percentile(telemetry_delay_s, 95)),
        "link_bps": down.rate_bps,
        "served_bps": 8.0 * service[0] / service[1],
    }


FLOWN = {  # link: the first guess of its capacity (the satellite's 4x high)
    "satellite": 4e6,
    "satellite-storm": 1e6,
}


@pytest.fixture(scope="module")
def flown() -> dict[tuple[str, str], dict[str, float]]:
    """Each link with each transport, 60 s of it on explicit times: CPU alone, so two at a time in
    processes of their own (spawned: nothing of this one's threads), each the same computation."""
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        runs = {
            (transport, link): pool.submit(fly, link, 60.0, first_guess_bps=guess, transport=transport)
            for transport in ("tcp", "udp")
            for link, guess in FLOWN.items()
        }
        return {job: run.result() for job, run in runs.items()}


@pytest.mark.parametrize("transport", ["tcp", "udp"])
def test_scene_stream_paces_itself_to_the_link_from_acks_alone(
    flown: dict[tuple[str, str], dict[str, float]], transport: str
) -> None:
    satellite, storm = flown[(transport, "satellite")], flown[(transport, "satellite-storm")]
    for got in (satellite, storm):
        assert got["most_in_flight"] == 1, got  # telemetry never waits behind more than one update
        assert got["applied"] >= 50 and got["acked"] >= got["applied"] - 1, got
        assert got["capacity_bps"] < got["link_bps"] * 20  # the wrong first guess did not run away
    # telemetry's wait behind one update: at most a quarter second of the link, beyond its delay
    # and jitter (measured: satellite p95 0.29-0.34 s, storm 0.57-0.91 s)
    assert satellite["telemetry_p95_s"] < 0.6 and storm["telemetry_p95_s"] < 1.5


def test_pacer_keeps_one_update_in_flight_and_gives_up_on_a_lost_one() -> None:
    pacer = ScenePacer(share=0.5, capacity_bps=1e6, burst_bytes=16_000)
    pacer.tick(0.0)
    assert pacer.allows() and pacer.update_bytes() == 16_000  # a quarter second of 1 Mbit/s is 31 kB
    pacer.sent(0.0, 16_000, seq=1)
    assert not pacer.allows() and pacer.update_bytes() == 8_000  # the half-size probe comes next
    pacer.tick(4.0)
    assert not pacer.allows()  # still waiting for shore
    pacer.tick(pacer.ack_timeout_s() + 0.1)
    assert pacer.lost == 1 and pacer.allows()
    pacer.acknowledged(9.0, 1)  # a late ack of a given-up update is ignored
    assert pacer.acked == 0
    pacer.tick(10.0)
    pacer.sent(10.0, 100_000)  # a big frame: the bucket goes into debt, refilled at half of 1 Mbit/s
    pacer.tick(11.0)
    assert pacer.tokens_bytes == pytest.approx(16_000 - 100_000 + 62_500) and not pacer.allows()
    pacer.tick(12.0)
    assert pacer.allows()
    assert ScenePacer(share=0.5, capacity_bps=256e3, burst_bytes=16_000).update_bytes() == 8_000


def test_relay_forwards_commands_and_answers_and_beats_with_shore_silence() -> None:
    cfg = VesselConfig()
    relay = Relay(cfg, panel, now_s=0.0)
    mode = OperatorMode(7, "hold")
    ack = CommandAck(7, "mode", "")
    out = relay.step(RelayInputs(commands=[("op/mode", mode)], acks=[ack], shore_heard=True), 0.0)
    assert ("goal/mode", mode) in out and ("ack", ack) in out
    beat = next(m for t, m in out if t == "heartbeat")
    assert isinstance(beat, Heartbeat) and beat.shore_heard
    assert not any(t == "heartbeat" for t, _ in relay.step(RelayInputs(), cfg.heartbeat_period_s / 2))
    late = relay.step(RelayInputs(), cfg.shore_timeout_s + 1.0)
    beat = next(m for t, m in late if t == "heartbeat")
    assert isinstance(beat, Heartbeat) and not beat.shore_heard and beat.shore_silence_s > cfg.shore_timeout_s
    state = sample_telemetry()
    now_s = cfg.shore_timeout_s + 2.0
    assert ("telemetry", state) in relay.step(RelayInputs(telemetry=(5, state)), now_s)
    again = relay.step(RelayInputs(telemetry=(5, state)), now_s + cfg.telemetry_period_s)
    assert not any(t == "telemetry" for t, _ in again)  # the same telemetry is not sent twice


def test_an_intent_waits_for_the_panel_goes_down_resolved_and_is_refused_beyond_its_stops() -> None:
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    intent = Intervention(5, "valve_1", math.radians(90), "")
    assert relay.step(RelayInputs(commands=[("op/intervene", intent)]), 0.0) == [
        ("heartbeat", Heartbeat(0.0, True))
    ]  # not recognised yet: it waits (shore resends)
    seen = np.array([[5.0, 0.0, -8.66, 1.0, 0.0, 0.0, 0.0]])  # the panel recognised 6 cm low
    by_shape = RecognisedObjects(
        ("panel",), seen, np.array([panel.plate_half_size_m]), np.ones(1), "shape", 0.5
    )
    out = relay.step(RelayInputs(commands=[("op/intervene", intent)], objects=by_shape), 0.5)
    assert [t for t, _ in out] == ["heartbeat"]  # no markers seen: it waits
    objects = dataclasses.replace(by_shape, method="texture+shape", sim_time_s=1.0)
    out = relay.step(RelayInputs(commands=[("op/intervene", intent)], objects=objects), 1.0)
    goal = next(m for t, m in out if t == "goal/intervene")
    assert isinstance(goal, InterventionGoal) and goal.command_id == 5
    assert goal.turn_rad == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(goal.pivot_m_world, [4.93, 0.0, -8.41])  # from the estimate, not the truth
    done = dataclasses.replace(
        sample_telemetry(), intervention_id=5, intervention_phase="done", turned_rad=math.radians(88)
    )
    relay.step(RelayInputs(telemetry=(1, done)), 2.0)
    again = Intervention(6, "valve_1", math.radians(45), "")  # from 88 deg: past the stop at 90
    ack = next(m for t, m in relay.step(RelayInputs(commands=[("op/intervene", again)]), 3.0) if t == "ack")
    assert isinstance(ack, CommandAck) and ack.command == "intervene"
    assert "turns between -90 and 90" in ack.reason
    lever = Intervention(7, "lever_0", math.radians(10), "")
    ack = next(m for t, m in relay.step(RelayInputs(commands=[("op/intervene", lever)]), 4.0) if t == "ack")
    assert isinstance(ack, CommandAck) and "is a lever" in ack.reason


def test_a_moved_estimate_goes_down_again_till_the_intervention_ends() -> None:
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    intent = Intervention(5, "valve_1", math.radians(90), "")

    def recognised(z_m: float, method: str = "texture") -> RecognisedObjects:
        return RecognisedObjects(
            ("panel",),
            np.array([[5.0, 0.0, z_m, 1.0, 0.0, 0.0, 0.0]]),
            np.array([panel.plate_half_size_m]),
            np.ones(1),
            method,
            1.0,
        )

    def goals(out: list) -> list[InterventionGoal]:
        return [m for t, m in out if t == "goal/intervene"]

    def phase(name: str) -> tuple[int, object]:
        return 1, dataclasses.replace(sample_telemetry(), intervention_id=5, intervention_phase=name)

    sent = RelayInputs(commands=[("op/intervene", intent)], objects=recognised(-8.66))
    first = goals(relay.step(sent, 1.0))
    assert len(first) == 1
    # recognition sharpens by 1 mm: not worth a resend (REFINE_M); by 5 cm: the same command, resolved anew
    assert goals(relay.step(RelayInputs(objects=recognised(-8.659), telemetry=phase("approach")), 2.0)) == []
    # an estimate from the shape alone (no marker seen: a restarted vessel's first) moves nothing
    shape_only = recognised(-8.30, "shape")
    assert goals(relay.step(RelayInputs(objects=shape_only, telemetry=phase("approach")), 2.5)) == []
    refined = goals(relay.step(RelayInputs(objects=recognised(-8.61), telemetry=phase("pre-grasp")), 3.0))
    assert len(refined) == 1 and refined[0].command_id == 5
    assert refined[0].grasp_m_world[2] - first[0].grasp_m_world[2] == pytest.approx(0.05)
    # the fingers closed: onboard takes the pivot's shift (the navigation's frame wandering)
    held = goals(relay.step(RelayInputs(objects=recognised(-8.605), telemetry=phase("turn")), 4.0))
    assert len(held) == 1 and held[0].pivot_m_world[2] - refined[0].pivot_m_world[2] == pytest.approx(0.005)
    relay.step(RelayInputs(telemetry=phase("done")), 5.0)
    assert relay.refining is None
    assert goals(relay.step(RelayInputs(objects=recognised(-8.55), telemetry=phase("done")), 6.0)) == []
    # one onboard refused (busy with another, a restarted shore's intent) is not refined: a resend
    # would be judged again once onboard is free, and the part worked twice
    other = Intervention(6, "valve_1", math.radians(90), "")
    assert len(goals(relay.step(RelayInputs(commands=[("op/intervene", other)]), 7.0))) == 1
    busy = CommandAck(6, "intervene", "the intervention on valve_1 is in progress (approach)")
    relay.step(RelayInputs(acks=[busy]), 8.0)
    assert relay.refining is None
    assert goals(relay.step(RelayInputs(objects=recognised(-8.50), telemetry=phase("done")), 9.0)) == []


def seen_turned(parts: dict[str, tuple[float, float]]) -> RecognisedObjects:
    """The panel where world.xml puts it, its parts measured at (angle [deg], confidence)."""
    tracker = PanelTracker(panel)
    tracker.estimate = Pose(np.eye(3), np.array(panel.position_m_world), 0.9)
    tracker.angles = {name: PartAngle(math.radians(a), c) for name, (a, c) in parts.items()}
    objects = tracker.objects(1.0)
    assert objects is not None
    return dataclasses.replace(objects, method="texture+shape")


def test_the_valves_vision_measures_are_believed_but_not_the_part_in_hand() -> None:
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    seen = {"valve_0": (30.0, 0.9), "valve_1": (-62.0, 0.9), "valve_2": (85.0, 0.2), "lever_0": (-45.0, 0.9)}
    relay.step(RelayInputs(objects=seen_turned(seen)), 1.0)
    believed = {name: math.degrees(a) for name, a in relay.believed_rad.items()}
    assert believed == {
        "valve_0": pytest.approx(30.0),
        "valve_1": pytest.approx(-62.0),
    }  # confident valves only
    # valve_1 in hand (onboard turning it): what vision sees of it, half hidden by the arm, is not believed
    turning = dataclasses.replace(
        sample_telemetry(), intervention_id=5, intervention_target="valve_1", intervention_phase="turn"
    )
    relay.step(RelayInputs(objects=seen_turned({"valve_1": (-40.0, 0.9)}), telemetry=(1, turning)), 2.0)
    assert math.degrees(relay.believed_rad["valve_1"]) == pytest.approx(-62.0)
    # the tool at valve_0 (a rebooted onboard's arm still on it): its bar hidden or held, not believed
    at_valve_0 = dataclasses.replace(
        sample_telemetry(),
        ee_position_m_world=np.add(panel.position_m_world, panel.valves["valve_0"]) - (0.05, 0.0, 0.0),
    )
    relay.step(RelayInputs(objects=seen_turned({"valve_0": (-12.0, 0.9)}), telemetry=(2, at_valve_0)), 2.5)
    assert math.degrees(relay.believed_rad["valve_0"]) == pytest.approx(30.0)
    # a bar at a and at a + 180 deg is one: taken nearest the belief
    relay.believed_rad["valve_2"] = math.radians(80.0)
    relay.step(RelayInputs(objects=seen_turned({"valve_2": (-88.0, 0.9)})), 3.0)
    assert math.degrees(relay.believed_rad["valve_2"]) == pytest.approx(90.0)  # 92, held in its range


def test_the_sonar_maps_while_the_cameras_bring_no_point_and_hands_back() -> None:
    perception = Perception(VesselConfig(sonar_fallback_s=5.0, perception_window_s=10.0))
    assert not perception.sonar_feeds(1000.0)  # nothing came yet: the fallback counts from the first message
    perception.received("sonar", 0, 100.0)
    assert perception.scene_source(101.0) == "" and not perception.sonar_feeds(104.9)
    assert perception.sonar_feeds(105.0)  # no camera cloud since the first message
    perception.received("depth", 1000, 101.0)
    assert not perception.sonar_feeds(105.9) and perception.sonar_feeds(106.0)
    perception.received("stereo", 0, 106.5)  # an empty cloud (murk, a blacked-out camera) is nothing
    perception.received("sonar", 300, 107.0)
    assert perception.sonar_feeds(107.0) and perception.scene_source(107.0) == "sonar"
    status = perception.status(108.0, None, 7.0, 42)
    assert status.scene_source == "sonar" and status.window_s == pytest.approx(8.0)
    assert status.points_per_s == pytest.approx({"depth": 125.0, "stereo": 0.0, "sonar": 37.5})
    assert status.recognition_confidence == 0.0 and status.recognition_method == ""
    assert status.scene_backlog_cells == 42
    perception.received("depth", 10, 109.0)  # the cameras see again
    assert not perception.sonar_feeds(109.0) and perception.scene_source(109.0) == "cameras"
    later = perception.status(116.0, None, 16.0, 0)  # the window slides past the first cloud
    assert later.points_per_s == pytest.approx({"depth": 1.0, "stereo": 0.0, "sonar": 30.0})


def marked_panel() -> RecognisedObjects:
    """The panel recognised from a frame that saw its markers."""
    return RecognisedObjects(
        ("panel",),
        np.array([[5.0, 0.0, -8.66, 1.0, 0.0, 0.0, 0.0]]),
        np.array([panel.plate_half_size_m]),
        np.ones(1),
        "texture",
        1.0,
    )


def working(intent: Intervention, boot: int, phase: str, turned_deg: float) -> tuple[int, Telemetry]:
    """Onboard's telemetry (boot `boot`) working `intent` in `phase`, the tool turned `turned_deg`
    from its grasp; with a sequence number new for each."""
    t = dataclasses.replace(
        sample_telemetry(),
        boot_id=boot,
        intervention_id=intent.command_id,
        intervention_target=intent.target,
        intervention_phase=phase,
        turned_rad=math.radians(turned_deg),
    )
    return boot * 1000 + round(abs(turned_deg) * 10), t


def test_an_intervention_handed_again_after_onboard_rebooted_mid_turn_starts_where_the_part_is() -> None:
    """valve_1 to be turned by 90 deg; onboard turned it 40 deg and rebooted. Shore hands the same
    intent again: it goes down resolved from 40 deg (the grasp where the bar now stands) for the 50
    deg left, the target unchanged; once done, the part is believed at 90 deg."""
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    objects = marked_panel()
    intent = Intervention(5, "valve_1", math.radians(90), "")

    def telemetry(boot: int, phase: str, turned_deg: float) -> tuple[int, Telemetry]:
        return working(intent, boot, phase, turned_deg)

    def goal(out: list) -> InterventionGoal:
        [sent] = [m for t, m in out if t == "goal/intervene"]
        return sent

    first = goal(relay.step(RelayInputs(commands=[("op/intervene", intent)], objects=objects), 1.0))
    assert first.turn_rad == pytest.approx(math.radians(90))
    approach = telemetry(1, "approach", 170.0)  # the tool's angle on its way, not the part's
    relay.step(RelayInputs(telemetry=approach), 2.0)
    relay.step(RelayInputs(telemetry=telemetry(1, "turn", 40.0)), 3.0)
    relay.step(RelayInputs(telemetry=telemetry(2, "", 0.0)), 4.0)  # a new boot: onboard rebooted
    again = goal(relay.step(RelayInputs(commands=[("op/intervene", intent)]), 5.0))
    assert again.command_id == 5 and again.turn_rad == pytest.approx(math.radians(50))
    between = (
        rotation_of(again.grasp_orientation_wxyz_world) @ rotation_of(first.grasp_orientation_wxyz_world).T
    )
    about_axis_deg = math.degrees(float(np.asarray(first.axis_world) @ pin.log3(between)))
    assert about_axis_deg == pytest.approx(40.0, abs=0.5)  # the grasp where the bar now stands
    relay.step(RelayInputs(telemetry=telemetry(2, "turn", 30.0)), 5.5)
    relay.step(RelayInputs(telemetry=telemetry(2, "release", 49.5)), 6.0)
    # rebooted again while letting go, the part at its target: handed again, it still goes down
    # (grasped, turned no further, let go: then done), not refused as "at 90 deg already"
    relay.step(RelayInputs(telemetry=telemetry(3, "", 0.0)), 7.0)
    last = goal(relay.step(RelayInputs(commands=[("op/intervene", intent)]), 8.0))
    assert last.turn_rad == pytest.approx(math.radians(0.5))
    relay.step(RelayInputs(telemetry=telemetry(3, "done", 0.5)), 9.0)
    assert relay.believed_rad["valve_1"] == pytest.approx(math.radians(90))


def test_a_lever_thrown_past_its_stop_by_the_tool_is_believed_at_the_stop_and_pushed_on_into_it() -> None:
    """lever_0 thrown down: the tool turns 55 deg (12 past the stop, the shaft twisting in the
    grip), the lever stops at -45. Onboard reboots while backing off; handed again, the lever goes
    down resolved from -45 with no turn left, its push toward the stop (negative), never up off
    it (a kill campaign's false done: resolved from -55, the push went 20 deg up)."""
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    objects = marked_panel()
    intent = Intervention(8, "lever_0", 0.0, "down")

    def telemetry(boot: int, phase: str, turned_deg: float) -> tuple[int, Telemetry]:
        return working(intent, boot, phase, turned_deg)

    first = [m for t, m in relay.step(RelayInputs(commands=[("op/intervene", intent)], objects=objects), 1.0)]
    assert first[0].turn_rad == pytest.approx(math.radians(-45))
    relay.step(RelayInputs(telemetry=telemetry(1, "turn", -30.0)), 2.0)
    relay.step(RelayInputs(telemetry=telemetry(1, "retreat", -54.7)), 3.0)
    relay.step(RelayInputs(telemetry=telemetry(2, "", 0.0)), 4.0)  # rebooted while backing off
    [again] = [
        m
        for t, m in relay.step(RelayInputs(commands=[("op/intervene", intent)]), 5.0)
        if t == "goal/intervene"
    ]
    assert again.turn_rad == 0.0 and math.copysign(1.0, again.turn_rad) == -1.0
    relay.step(RelayInputs(telemetry=telemetry(2, "turn", -1.0)), 6.0)
    relay.step(RelayInputs(telemetry=telemetry(2, "done", -12.0)), 7.0)
    assert relay.believed_rad["lever_0"] == pytest.approx(math.radians(-45))


def test_a_restarted_vessel_takes_on_onboards_intervention_and_hands_it_again_from_the_part() -> None:
    """The vessel restarted while onboard worked valve_1 (shore's intent was taken before: it is
    not sent again). From onboard's telemetry the new vessel takes the intervention on and follows
    the turn; onboard reboots 60 deg into it, shore hands it again: it goes down from 60 deg for
    the 30 left (it went down from the rest angle, where the bar no longer is, and the fingers
    were blocked by it: every-station-killed)."""
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    intent = Intervention(5, "valve_1", math.radians(90), "")

    def telemetry(boot: int, phase: str, turned_deg: float) -> tuple[int, Telemetry]:
        seq, t = working(intent, boot, phase, turned_deg)
        return seq, dataclasses.replace(t, turn_goal_rad=math.radians(90.4))  # from -0.4 deg, as seen

    relay.believed_rad["valve_1"] = math.radians(-0.2)  # seen so before: the target is held at 90
    relay.step(RelayInputs(objects=marked_panel(), telemetry=telemetry(1, "turn", 20.0)), 1.0)
    relay.step(RelayInputs(telemetry=telemetry(1, "turn", 60.0)), 2.0)
    relay.step(RelayInputs(telemetry=telemetry(2, "", 0.0)), 3.0)  # onboard rebooted
    out = relay.step(RelayInputs(commands=[("op/intervene", intent)]), 4.0)
    [again] = [m for t, m in out if t == "goal/intervene"]
    assert isinstance(again, InterventionGoal) and again.turn_rad == pytest.approx(math.radians(30.2))


def test_a_turn_ending_a_little_past_its_stop_ends_at_the_stop() -> None:
    """valve_1 seen at 0.4 deg (vision's noise about its rest) and asked to turn by 90: the goal
    turns it to its stop at 90 (it was refused as past it, and a restarted vessel's mission
    stopped there); 6 deg past is still refused."""
    relay = Relay(VesselConfig(), panel, now_s=0.0)
    relay.believed_rad["valve_1"] = math.radians(0.4)
    intent = Intervention(5, "valve_1", math.radians(90), "")
    out = relay.step(RelayInputs(commands=[("op/intervene", intent)], objects=marked_panel()), 1.0)
    [goal] = [m for t, m in out if t == "goal/intervene"]
    assert isinstance(goal, InterventionGoal) and math.degrees(goal.turn_rad) == pytest.approx(89.6)
    relay.believed_rad["valve_2"] = math.radians(6.0)
    out = relay.step(
        RelayInputs(commands=[("op/intervene", Intervention(6, "valve_2", math.radians(90), ""))]), 2.0
    )
    [ack] = [m for t, m in out if t == "ack"]
    assert isinstance(ack, CommandAck) and "turns between -90 and 90" in ack.reason
