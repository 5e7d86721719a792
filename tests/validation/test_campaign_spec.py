"""Campaign files: a good one loads (globs relative to the file, duplicates once, seeds as a count
or a list); each bad input is refused at load naming the file, the field and what is allowed;
the shipped library campaign loads and plans."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from campaign_files import CAMPAIGN, ROOT, write_files

from abyss.common.errors import ConfigError
from abyss.validation.campaign.plan import plan
from abyss.validation.campaign.spec import load_campaign


def test_a_campaign_loads_its_scenarios_by_globs_relative_to_its_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = write_files(
        tmp_path, CAMPAIGN.replace('"../scenarios/*.toml"', '"../scenarios/*.toml", "../scenarios/beta.toml"')
    )
    elsewhere = tmp_path / "x" / "y"
    elsewhere.mkdir(parents=True)
    monkeypatch.chdir(elsewhere)  # ../scenarios from here is tmp/x/scenarios: nothing
    campaign = load_campaign(path)
    assert [s.name for s in campaign.scenarios] == ["alpha", "beta"]  # beta named twice, once
    assert campaign.scenarios[0].path == (tmp_path / "scenarios" / "alpha.toml").resolve()
    assert campaign.seeds == (0, 1, 2)
    assert (campaign.time, campaign.keep, campaign.min_pass_rate, campaign.matrix) == (
        "lockstep",
        "failing",
        1.0,
        (),
    )
    assert campaign.min_rate("alpha") == 1.0


def test_seeds_as_a_list_rates_per_scenario_and_an_exclusion(tmp_path: Path) -> None:
    text = (
        CAMPAIGN.replace("seeds = 3", "seeds = [3, 7, 11]")
        + 'exclude = ["../scenarios/beta.toml"]\nmin_pass_rate = 0.9\n'
        + "[min_pass_rate_of]\nalpha = 0.5\n"
    )
    campaign = load_campaign(write_files(tmp_path, text))
    assert campaign.seeds == (3, 7, 11)
    assert [s.name for s in campaign.scenarios] == ["alpha"]
    assert campaign.min_rate("alpha") == 0.5 and campaign.min_rate("gamma") == 0.9


BAD = [
    ('colour = "red"\n', "colour", "allowed: description, exclude, keep, matrix"),
    ('[matrix]\n"nonsense.x" = [1]\n', "matrix.nonsense.x", "allowed: cpu, hybrid, links, mavlink, mission"),
    ('[matrix]\n"nonsense.x" = [1]\n', "matrix.nonsense.x", "links.<hop> (rov, tether, satellite)"),
    ('[matrix]\n"links.radio" = ["ideal"]\n', "matrix.links.radio", "rov, tether, satellite"),
    ('[matrix]\n"links.satellite" = ["fast"]\n', "matrix.links.satellite", "satellite-storm"),
    ('[matrix]\n"links.satellite" = []\n', "matrix.links.satellite", "at least one value"),
    ('[matrix]\n"links.satellite" = ["satellite", "satellite"]\n', "matrix.links.satellite", "twice"),
    ("[matrix]\n", "matrix", "leave it out"),
    ('[matrix]\n"events[0].colour" = [1]\n', "matrix.events[0].colour", "at_s, phase, hop"),
    ('[matrix]\n"events[1].at_s" = [1.0]\n', "matrix.events[1].at_s", "scenario alpha"),
    ('[matrix]\n"events[0].at_s" = ["soon"]\n', "matrix.events[0].at_s", "expected a finite number"),
    (
        '[matrix]\n"events[0].station" = ["vessel"]\n',
        "matrix.events[0].station",
        "link event: it takes no station",
    ),
    ('[matrix]\n"events.at_s" = [1.0]\n', "matrix.events.at_s", "events[i].<field>"),
    (
        '[matrix]\n"mission.position_tolerance_m" = [0.1, -1]\n',
        "matrix.mission.position_tolerance_m",
        "positive",
    ),
    ('[matrix]\n"simulation.water" = ["murky"]\n', "matrix.simulation.water", "IA"),
    ("[matrix]\nseed = [1, 2]\n", "matrix.seed", "seeds"),
    ('[matrix]\n"time.mode" = ["sim"]\n', "matrix.time.mode", "campaign's time"),
    ('time = "warp"\n', "time", "lockstep, sim, real"),
    ('keep = "some"\n', "keep", "failing, all, none"),
    ("min_pass_rate = 1.5\n", "min_pass_rate", "from 0 to 1"),
    ("[min_pass_rate_of]\ngamma = 0.5\n", "min_pass_rate_of.gamma", "alpha, beta"),
    ("[min_pass_rate_of]\nalpha = -0.1\n", "min_pass_rate_of.alpha", "from 0 to 1"),
    ('exclude = ["../scenarios/zeta.toml"]\n', "exclude[0]", "matches no file"),
    ('exclude = ["../scenarios/*.toml"]\n', "scenarios", "nothing to run"),
]


@pytest.mark.parametrize(("extra", "field", "allowed"), BAD)
def test_a_bad_campaign_is_refused_naming_file_field_and_what_is_allowed(
    tmp_path: Path, extra: str, field: str, allowed: str
) -> None:
    path = write_files(tmp_path, CAMPAIGN + extra)
    with pytest.raises(ConfigError) as error:
        load_campaign(path)
    assert error.value.field == field, str(error.value)
    assert allowed in str(error.value), str(error.value)
    assert error.value.source == str(path)


@pytest.mark.parametrize(
    ("old", "new", "field", "allowed"),
    [
        ("seeds = 3", "seeds = 0", "seeds", "a count of at least 1"),
        ("seeds = 3", "seeds = []", "seeds", "non-empty list"),
        ("seeds = 3", "seeds = [1, 1]", "seeds", "distinct"),
        ("seeds = 3", "", "seeds", "is required"),
        ('"../scenarios/*.toml"', '"scenarios/*.toml"', "scenarios[0]", "matches no file"),
        ('scenarios = ["../scenarios/*.toml"]', "scenarios = []", "scenarios", "at least one"),
        ('name = "small"', 'name = "a small one"', "name", "[A-Za-z0-9_-]"),
    ],
)
def test_bad_seeds_scenarios_or_name_are_refused(
    tmp_path: Path, old: str, new: str, field: str, allowed: str
) -> None:
    path = write_files(tmp_path, CAMPAIGN.replace(old, new))
    with pytest.raises(ConfigError) as error:
        load_campaign(path)
    assert (error.value.field, error.value.source) == (field, str(path)), str(error.value)
    assert allowed in str(error.value)


def test_a_bad_scenario_fails_naming_its_own_file(tmp_path: Path) -> None:
    write_files(tmp_path)
    bad = tmp_path / "scenarios" / "gamma.toml"
    bad.write_text('name = "gamma"\nuse = "fun"\nduration_s = 1\n[[assert]]\nkind = "stations"\n')
    with pytest.raises(ConfigError) as error:
        load_campaign(tmp_path / "campaigns" / "small.toml")
    assert (error.value.field, error.value.source) == ("scenario.use", str(bad.resolve()))


def test_an_unreadable_campaign_names_itself(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("name = \n")
    with pytest.raises(ConfigError, match=r"broken\.toml: campaign: cannot read"):
        load_campaign(path)


def test_the_shipped_library_campaign_loads_and_plans() -> None:
    campaign = load_campaign(ROOT / "campaigns" / "library.toml")
    library = {p.stem for p in (ROOT / "scenarios").glob("*.toml")}
    names = [s.name for s in campaign.scenarios]
    assert set(names) == library - {"external-onboard", "satellite-down"} and len(names) >= 10
    assert campaign.seeds == (0, 1, 2, 3, 4)
    assert campaign.matrix == (("links.satellite", ("satellite", "satellite-storm")),)
    assert campaign.min_rate("sensor-noise") == 0.8 and campaign.min_rate("nominal") == 1.0
    runs = plan(campaign)
    assert len(runs) == len(names) * 2 * 5
    assert {r.scenario.links["satellite"] for r in runs} == {"satellite", "satellite-storm"}
    assert {r.scenario_name for r in runs if r.replayable} >= {"nominal", "sensor-noise", "turbid"}


def test_a_ray_address_that_does_not_answer_fails_at_once_with_the_fix(tmp_path: Path) -> None:
    """Ray itself would retry a dead address for minutes; the command says so at once, and leaves
    no campaign directory behind (the same command with a right address then runs)."""
    import socket
    import subprocess
    import sys

    with socket.socket() as probe:  # a port nothing listens on once closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    path = write_files(tmp_path, CAMPAIGN)
    address = f"127.0.0.1:{port}"
    command = ["campaign", "run", str(path), "--address", address, "--out", str(tmp_path / "out")]
    done = subprocess.run(
        [sys.executable, "-P", "-m", "abyss.cli", *command],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"--address: no Ray cluster answers at 127.0.0.1:{port} (Connection refused)" in done.stderr
    assert "`ray start --head`" in done.stderr and not (tmp_path / "out").exists()


def test_the_shipped_kill_campaign_kills_every_station_over_the_mission_in_lockstep() -> None:
    runs = plan(load_campaign(ROOT / "campaigns" / "kills.toml"))
    kills = {(r.scenario.events[0].station, r.scenario.events[0].at_s) for r in runs}
    assert {station for station, _ in kills} == {"simulation", "onboard", "vessel", "onshore"}
    assert len(kills) == 36 and len(runs) == 108
    assert all(r.replayable and r.scenario.holds_s == (r.scenario.events[0].at_s,) for r in runs)
    assert all(r.scenario.restart for r in runs)


def test_robot_and_site_are_matrix_axes_by_shipped_name_or_directory(tmp_path: Path) -> None:
    """`robot` and `site` vary the packages a run flies (simulation.robot, simulation.site): a
    shipped package by its name, a directory relative to the campaign file; each run's
    configuration names the package it runs, and one that is no package is refused naming the key."""
    package = tmp_path / "my_robot"
    shutil.copytree(ROOT / "description" / "models" / "robots" / "workclass", package)
    text = CAMPAIGN + '[matrix]\nrobot = ["bluerov2_heavy_alpha5", "../my_robot"]\nsite = ["valve_panel"]\n'
    campaign = load_campaign(write_files(tmp_path, text))
    robots = {run.scenario.configuration.simulation.robot for run in plan(campaign)}
    shipped = ROOT / "description" / "models" / "robots" / "bluerov2_heavy_alpha5"
    assert robots == {str(shipped.resolve()), str(package.resolve())}
    assert {run.scenario.configuration.simulation.site for run in plan(campaign)} == {
        str((ROOT / "description" / "models" / "sites" / "valve_panel").resolve())
    }
    with pytest.raises(ConfigError, match=r"matrix\.robot: .*not a robot package.*bluerov2_heavy_alpha5"):
        load_campaign(write_files(tmp_path, CAMPAIGN + '[matrix]\nrobot = ["../nowhere"]\n'))
