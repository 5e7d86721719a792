"""`abyss replay RUN_DIR`'s run directory and configuration, without a system: a directory that is
not there is said to be missing; a campaign's directory and a run id under it are told apart; a
run a scenario or a campaign ran in lockstep (holds, its paths on the host that ran it) replays on
the wall clock with the user's options on top."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from abyss.cli import main, parser
from abyss.cli.record import replay_config, run_directory
from abyss.common.errors import ConfigError
from abyss.config import load
from abyss.launch.start import CONFIG_FILE, Replayed, checked_external, run_config
from abyss.validation.campaign.store import PLAN_FILE, RUNS_DIR

RUN_ID = "3f9a1c0d5e6b7a81"


def campaign_run(tmp_path: Path) -> Path:
    """A run directory as a campaign keeps it (`<campaign>/runs/<run id>/`): its config.json as
    the worker's `abyss up` wrote it, in lockstep with the scenario's holds, every path in it
    under the worker's own run directory."""
    campaign = tmp_path / "campaign"
    run = campaign / RUNS_DIR / RUN_ID
    run.mkdir(parents=True)
    (campaign / PLAN_FILE).write_text("{}")
    config = load(overrides=["time.mode=lockstep", "time.holds_s=[2.0, 3.0, 4.0]", "system=small-1"])
    worker = tmp_path / "elsewhere" / "00-short-faults"
    (run / CONFIG_FILE).write_text(run_config(config, worker, 12.0).to_json())
    return run


def replay_args(run: Path, *more: str) -> object:
    return parser().parse_args(["replay", str(run), "--as", "simulation", "--as", "vessel", *more])


def test_a_run_directory_that_is_not_there_is_said_so(capsys: pytest.CaptureFixture[str]) -> None:
    for command in (
        ["replay", "runs/nope", "--as", "onboard"],
        ["replay", "runs/nope"],
        ["view", "runs/nope"],
    ):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "no such run directory: runs/nope" in err and "--record none" not in err, err


def test_a_campaign_directory_and_a_run_id_under_it(tmp_path: Path) -> None:
    run = campaign_run(tmp_path)
    campaign = run.parents[1]
    with pytest.raises(ConfigError, match=rf"is a campaign directory: .*{RUN_ID}.*abyss campaign replay"):
        run_directory(campaign)
    assert run_directory(run) == run
    assert run_directory(campaign / RUN_ID[:8]) == run  # as the campaign's report names its runs
    with pytest.raises(ConfigError, match="no such run directory"):
        run_directory(campaign / "ffff")


def test_a_lockstep_run_replays_on_the_wall_clock_with_the_users_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = campaign_run(tmp_path)
    config = replay_config(replay_args(run, "--set", "onboard.kp_position=1.2"), run)
    assert config.system == "small-1" and config.onboard.kp_position == 1.2
    assert (config.time.mode, config.time.holds_s, config.time.end_s) == ("real", (), 0.0)
    assert "ran in lockstep time; its replay runs on the wall clock" in capsys.readouterr().out
    # what refused it: a replay on the simulation's clock (--replay with --time sim, the user
    # never passed either), then the holds without lockstep
    replayed = Replayed(run, ("simulation", "vessel"))
    checked_external(config, (), False, replayed)
    # the replay's own directory in every path, not the worker's
    replay_dir = tmp_path / "replay"
    again = run_config(config, replay_dir, None)
    assert again.record.directory == str(replay_dir / "record")
    assert again.simulation.state_file.startswith(str(replay_dir))
    # --time asked for explicitly is the user's, and refused as before
    config = replay_config(replay_args(run, "--time", "sim"), run)
    with pytest.raises(ConfigError, match="--replay"):
        checked_external(config, (), False, replayed)


def test_a_run_without_its_configuration_replays_on_the_defaults(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    config = replay_config(replay_args(run, "--seed", "4"), run)
    assert config.seed == 4 and config.time.mode == "real"
    (run / CONFIG_FILE).write_text("{not json")
    with pytest.raises(ConfigError, match=rf"{CONFIG_FILE}: config: cannot read"):
        replay_config(replay_args(run), run)
    real = dataclasses.replace(load(), system="mine")
    (run / CONFIG_FILE).write_text(real.to_json())
    assert replay_config(replay_args(run), run).system == "mine"
