"""Shore's scene stream as a core (abyss.scene.receiver.ShoreScene), without Zenoh: each update
acknowledged, applied in order, a gap (or bytes that do not decode) answered with a request for
a snapshot, none asked while the map is held, and the map kept across a new stream. Real models,
real updates through the codec."""

from __future__ import annotations

import dataclasses

from walls import occupied, updates, wall_model

from abyss.scene.receiver import ShoreScene

REQUEST_PERIOD_S = 1.0


def test_updates_are_acknowledged_and_applied_in_order() -> None:
    model = wall_model(2.03, (200, 8, 8))
    sent = updates(model, sim_time_s=7.5)
    assert len(sent) >= 3 and sent[0].kind == "snapshot"
    shore = ShoreScene(REQUEST_PERIOD_S)
    out = shore.step(sent, 10.0)
    assert [a.scene_seq for a in out.acks] == [u.scene_seq for u in sent] == list(range(len(sent)))
    assert [a.index for a in out.applied] == list(range(len(sent)))
    assert not out.rejected and out.request is None and not out.new_stream
    assert set(shore.receiver.colors) == occupied(model)
    assert shore.receiver.binary() == model.binary()
    assert shore.sim_time_s == 7.5 and shore.update_bytes > 0 and shore.requests == 0
    # what each update set, for the viewer: its occupied cells, red
    assert sum(len(a.centres_m_world) for a in out.applied) >= len(occupied(model))
    assert all((a.colors == (200, 8, 8)).all() for a in out.applied)
    # one again (a duplicate on the link): acknowledged, not applied, nothing asked
    again = shore.step([sent[1]], 10.1)
    assert [a.scene_seq for a in again.acks] == [1] and not again.applied and again.request is None
    assert shore.receiver.applied == len(sent)


def test_without_a_map_shore_asks_for_a_snapshot_every_request_period() -> None:
    shore = ShoreScene(REQUEST_PERIOD_S)
    first = shore.step([], 0.0)
    assert first.request is not None and first.request.reason == "no map yet"
    assert first.request.last_seq == -1
    assert shore.step([], 0.5).request is None  # within the period
    assert shore.step([], 1.0).request is not None and shore.requests == 2
    model = wall_model(2.03, (200, 8, 8))
    assert shore.step(updates(model), 1.5).request is None
    assert shore.step([], 5.0).request is None  # a map held: nothing to ask
    assert shore.requests == 2


def test_a_gap_asks_for_a_snapshot_at_once_and_the_snapshot_ends_it() -> None:
    model = wall_model(2.03, (200, 8, 8))
    first, _lost, *rest = updates(model)
    shore = ShoreScene(REQUEST_PERIOD_S)
    shore.step([], 0.0)  # asked: no map yet
    out = shore.step([first, rest[0]], 0.2)  # within the period, but a gap asks at once
    assert [a.scene_seq for a in out.acks] == [0, 2]  # both acknowledged: the vessel paces by them
    assert [a.index for a in out.applied] == [0]
    assert out.request is not None and out.request.reason == "missed an update"
    assert out.request.last_seq == 0
    assert shore.receiver.tree is None and shore.receiver.gaps == 1
    assert shore.step(rest[1:], 0.4).applied == []  # past the gap: nothing applied
    model.request_snapshot()
    resync = updates(model)
    assert resync[0].kind == "snapshot"
    healed = shore.step(resync, 0.6)
    assert len(healed.applied) == len(resync) and healed.request is None
    assert shore.receiver.binary() == model.binary()
    assert shore.step([], 5.0).request is None


def test_an_update_that_does_not_decode_is_rejected_and_asks_for_a_snapshot() -> None:
    model = wall_model(2.03, (200, 8, 8))
    first, *_ = updates(model)
    bad = dataclasses.replace(first, octree=b"# Octomap OcTree binary file\n")
    shore = ShoreScene(REQUEST_PERIOD_S)
    out = shore.step([bad], 0.0)
    assert [a.scene_seq for a in out.acks] == [0]
    assert len(out.rejected) == 1 and out.rejected[0][0] == 0 and "binary" in out.rejected[0][1]
    assert not out.applied and out.request is not None
    assert shore.step([first], 0.1).applied[0].index == 0


def test_a_new_stream_goes_onto_the_map_shore_holds() -> None:
    before, after = wall_model(2.03, (200, 8, 8)), wall_model(-2.03, (8, 8, 200))  # a restarted vessel
    shore = ShoreScene(REQUEST_PERIOD_S)
    assert not shore.step(updates(before), 0.0).new_stream
    out = shore.step(updates(after), 1.0)
    assert out.new_stream and out.request is None and out.acks[0].scene_seq == 0
    assert set(shore.receiver.colors) == occupied(before) | occupied(after)
    assert not occupied(before) & occupied(after)  # two walls apart: both kept
    assert shore.receiver.new_streams == 1 and shore.receiver.gaps == 0
