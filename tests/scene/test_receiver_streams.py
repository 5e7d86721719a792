"""Scene streams on shore (abyss.scene.receiver.SceneReceiver): a restarted vessel's new SceneModel starts
a new stream whose updates go onto the map shore holds (what the vessel saw before stays), while a
snapshot of the same stream after a gap replaces the map. Synthetic walls, no rendering, each of
one colour in the middle of a step of `COLOR_STEP` (what goes to shore)."""

from __future__ import annotations

import numpy as np
from walls import RESOLUTION_M, SENSOR_M_WORLD, occupied, updates, wall, wall_model

from abyss.scene.model import SceneModel
from abyss.scene.octree import HYSTERESIS_LOG_ODDS, cell_keys, iterate_leaves, leaves_to_cells
from abyss.scene.receiver import SceneReceiver


def test_each_scene_model_has_its_own_stream_id() -> None:
    first, second = SceneModel(RESOLUTION_M, 8.0), SceneModel(RESOLUTION_M, 8.0)
    assert first.stream_id != second.stream_id
    first.insert(*wall(2.03, (200, 8, 8)), SENSOR_M_WORLD)
    assert {u.stream_id for u in updates(first)} == {first.stream_id}


def test_a_new_streams_updates_go_onto_the_map_shore_holds() -> None:
    before, after = wall_model(2.03, (200, 8, 8)), wall_model(-2.03, (8, 8, 200))  # a restarted vessel
    receiver = SceneReceiver()
    assert {receiver.apply(u) for u in updates(before)} == {"applied"}
    cells_before = occupied(before)
    assert set(receiver.colors) == cells_before and len(cells_before) > 50
    assert receiver.new_streams == 0

    first, *later = updates(after)
    assert first.kind == "snapshot" and first.scene_seq == 0 and later  # then deltas
    assert receiver.apply(first) == "applied"
    assert receiver.new_streams == 1 and receiver.stream_id == after.stream_id
    assert cells_before < set(receiver.colors)  # kept, and the new stream's first cells added
    assert [receiver.apply(u) for u in later] == ["applied"] * len(later)
    assert set(receiver.colors) == cells_before | occupied(after)
    assert not cells_before & occupied(after)  # two walls apart: the union is more than either
    assert {receiver.colors[k] for k in cells_before} == {(200, 8, 8)}
    assert {receiver.colors[k] for k in occupied(after)} == {(8, 8, 200)}
    assert receiver.gaps == 0 and receiver.new_streams == 1


def test_a_snapshot_of_the_same_stream_after_a_gap_replaces_the_map() -> None:
    before, after = wall_model(2.03, (200, 8, 8)), wall_model(-2.03, (8, 8, 200))
    receiver = SceneReceiver()
    for update in updates(before):
        receiver.apply(update)
    first, lost, *rest = updates(after)
    assert receiver.apply(first) == "applied"
    assert occupied(before) < set(receiver.colors)
    assert rest and receiver.apply(rest[0]) == "gap"  # `lost` never came
    assert receiver.tree is None and receiver.gaps == 1
    after.request_snapshot()
    resync = updates(after)
    assert resync[0].kind == "snapshot" and resync[0].stream_id == after.stream_id
    assert resync[0].scene_seq > lost.scene_seq
    assert [receiver.apply(u) for u in resync] == ["applied"] * len(resync)
    assert set(receiver.colors) == occupied(after)  # the restarted vessel's map only
    assert receiver.binary() == after.binary()
    assert receiver.new_streams == 1


def test_a_new_stream_whose_first_update_was_lost_is_a_gap() -> None:
    before, after = wall_model(2.03, (200, 8, 8)), wall_model(-2.03, (8, 8, 200))
    receiver = SceneReceiver()
    for u in updates(before):
        receiver.apply(u)
    _lost, second, *_ = updates(after)
    assert second.scene_seq == 1
    assert receiver.apply(second) == "gap"  # not taken as the stream's start: shore asks for a snapshot
    assert receiver.tree is None and receiver.new_streams == 0


def test_a_published_cell_goes_again_only_once_its_log_odds_are_well_past_the_threshold() -> None:
    """A wall seen three times, then seen through (rays to a wall beyond pass its middle, a miss
    each): while a cell's log-odds lie in the hysteresis band, where OctoMap's maximum likelihood
    already calls it free, shore keeps it as sent; once past the band it goes free."""
    model = wall_model(2.03, (200, 8, 8))
    for _ in range(2):
        model.insert(*wall(2.03, (200, 8, 8)), SENSOR_M_WORLD)
    updates(model)
    sent = occupied(model)
    band_seen = False
    for _ in range(12):
        model.insert(*wall(4.03, (8, 200, 8)), SENSOR_M_WORLD)
        updates(model)
        leaves = iterate_leaves(model.tree, (np.array([1.95, -0.6, -0.6]), np.array([2.15, 0.6, 0.6])))
        keys, owners = leaves_to_cells(leaves.centres_m, leaves.sizes_m, RESOLUTION_M)
        log_odds = dict(zip(keys.tolist(), leaves.log_odds[owners], strict=True))
        on_shore = occupied(model)
        for key in sent:
            past = log_odds[key] < -HYSTERESIS_LOG_ODDS
            assert (key in on_shore) != past, (key, log_odds[key])
            band_seen |= -HYSTERESIS_LOG_ODDS <= log_odds[key] < 0
    assert band_seen  # some cell was free by the map and still occupied on shore
    assert len(sent - occupied(model)) >= 25  # the middle of the wall, seen through


def test_when_the_updates_go_out_does_not_change_what_shore_ends_with() -> None:
    """A wall seen through (a miss on each of its cells), then seen (a hit: log-odds 0.44, inside
    the hysteresis band): whether the updates go out after each cloud or only at the end, each
    cell is judged against the state decided for it first, queued or sent, so shore ends with
    the same map: the wall's cells as first decided, free (the link's pacing once decided it)."""
    shores = []
    for send_each in (True, False):
        model = SceneModel(RESOLUTION_M, 8.0, max_update_bytes=200)
        receiver = SceneReceiver()
        for x_m in (4.03, 2.03):
            model.insert(*wall(x_m, (200, 8, 8)), SENSOR_M_WORLD)
            for update in updates(model) if send_each else ():
                receiver.apply(update)
        for update in updates(model):
            receiver.apply(update)
        shores.append((occupied(model), set(model.published.keys.tolist())))
    assert shores[0] == shores[1]
    points = wall(2.03, (0, 0, 0))[0]
    seen_through = points[np.abs(points[:, 1:]).max(axis=1) < 0.2]  # within the rays to the far wall
    near = set(cell_keys(seen_through, RESOLUTION_M).tolist())
    occupied_cells, known_cells = shores[0]
    assert len(near) >= 9 and near <= known_cells and not near & occupied_cells  # sent, free
    assert len(occupied_cells) >= 100  # the far wall
