"""Link profiles read through the one typed reader (common.reading): a bad field in profiles.toml,
`abyss link set` or a config names the file and profile, the field and what is allowed."""

from __future__ import annotations

from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.config.linkprofile import FIELDS, LinkProfile, WrittenProfile, load_profiles, profile


def test_every_written_field_has_its_hint_and_its_attribute() -> None:
    assert list(FIELDS) == [f for f in WrittenProfile.__dataclass_fields__]
    assert {attr for attr, _, _ in FIELDS.values()} <= set(LinkProfile.__dataclass_fields__)


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"warp": "1"}, r"^warp: unknown field; allowed: correlation, corrupt, delay, .*transport$"),
        ({"transport": "sctp"}, r"^transport: 'sctp' not one of tcp, udp$"),
        ({"distribution": 3}, r"^distribution: expected a string, got 3$"),
        ({"deliver_corrupt": "maybe"}, r"^deliver_corrupt: expected true or false, got 'maybe'$"),
        ({"queue_limit": "lots"}, r"^queue_limit: expected a whole number, got 'lots'$"),
        ({"queue_limit": 0}, r"^queue_limit: 0 is not a whole number in \[1, 1000000\]$"),
        ({"seed": "-1"}, r"^seed: -1 is not a whole number in \[0, "),
        ({"delay": 5}, r"^delay: 5 has no unit; write it like '150ms'"),
        ({"trace": "nope"}, r"^trace: 'nope': .*; shipped: vsat-geo"),
    ],
)
def test_a_bad_field_names_the_field_and_what_is_allowed(fields: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        profile("tether", fields)


def test_command_line_strings_are_read_as_their_types() -> None:
    p = profile("tether", {"deliver_corrupt": "true", "queue_limit": "20", "seed": "7", "loss": "2%"})
    assert (p.deliver_corrupt, p.queue_limit_packets, p.seed, p.loss) == (True, 20, 7, 0.02)
    for name, written in load_profiles().items():  # each profile as written reads back the same
        assert LinkProfile(name=name).with_fields(written.fields()) == written


def test_a_bad_profiles_file_names_the_file_the_profile_and_the_field(tmp_path: Path) -> None:
    path = tmp_path / "profiles.toml"
    path.write_text('[slow]\nrate = "1mbit"\nqueue_limt = 10\n')
    with pytest.raises(ConfigError) as info:
        load_profiles(path)
    assert str(info.value).startswith(f"{path} [slow]: queue_limt: unknown field; allowed: ")
    assert "queue_limit" in info.value.reason
