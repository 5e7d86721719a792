"""`abyss campaign replay DIR RUN_ID`: one of a campaign's runs again, on this machine, from what
the campaign directory holds (the plan carries each run's scenario, variant and seed, so neither
the scenario file nor the cluster is needed), then compared with the run the campaign kept: in
lockstep byte for byte (onboard's telemetry as recorded, `control.csv`, and every message each
station sent, per boot), otherwise only its verdict, since a run on the wall clock repeats only
statistically."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from abyss.common.errors import ConfigError
from abyss.interface import keys
from abyss.recording.reader import read_file
from abyss.validation.campaign.plan import RunSpec
from abyss.validation.campaign.store import Store
from abyss.validation.scenario.runner import Result, run_scenario

Sent = dict[tuple[str, str, int], bytes]  # (the life's recording, key past the system, seq) -> payload


def find(directory: Path, run_id: str) -> RunSpec:
    """The planned run whose id starts with `run_id` (exactly one)."""
    runs = list(Store(directory).read_plan().all_runs)
    matches = [r for r in runs if r.run_id.startswith(run_id)]
    if len(matches) != 1:
        some = ", ".join(r.run_id for r in (matches or runs)[:5])
        raise ConfigError(
            "RUN_ID", f"{run_id!r} names {len(matches)} of the campaign's {len(runs)} runs (e.g. {some})"
        )
    return matches[0]


def sent_messages(run_dir: Path, station: str) -> Sent:
    """Every message `station` sent in a run, in each of its lives (a restarted station records
    to `<station>-<life>.mcap`), from its recordings (empty without one)."""
    lives = sorted((run_dir / "record").glob(f"{station}.mcap")) + sorted(
        (run_dir / "record").glob(f"{station}-*.mcap")
    )
    return {
        (path.name, r.key.split("/", 2)[-1], r.seq): r.payload  # the key without the run's system id
        for path in lives
        for r in read_file(path).records
        if r.direction == "sent"
    }


def _tail_only(first: Sent, second: Sent) -> bool:
    """True if the messages one run sent and the other did not all come after what both sent, each
    key's in each life: the two ran alike, one of them on to a later end."""
    last: dict[tuple[str, str], int] = {}
    for life, key, seq in first.keys() & second.keys():
        last[(life, key)] = max(seq, last.get((life, key), -1))
    extra_first, extra_second = first.keys() - second.keys(), second.keys() - first.keys()
    if extra_first and extra_second:
        return False
    return all(seq > last.get((life, key), -1) for life, key, seq in extra_first | extra_second)


def differences(original: Path, again: Path) -> tuple[list[str], int]:
    """Where two runs' bytes differ (empty: identical, end included), and the messages compared.
    In lockstep a run ends on the same period every time, its duration's or, stopped once its
    mission is done, the period its lease ends on (timing.lockstep): a different end is a
    difference, said with how far each went."""
    found: list[str] = []
    csv = [(run / "control.csv").read_bytes().splitlines(keepends=True) for run in (original, again)]
    rows = min(map(len, csv))
    if csv[0][:rows] != csv[1][:rows]:
        found.append("control.csv differs")
    compared, tails = 0, []
    for station in keys.STATIONS:
        first, second = sent_messages(original, station), sent_messages(again, station)
        both = first.keys() & second.keys()
        compared += len(both)
        if not _tail_only(first, second):
            found.append(f"{station} sent {len(first)} messages, then {len(second)}, not just later")
        elif changed := sorted(k for k in both if first[k] != second[k]):
            life, key, seq = changed[0]
            found.append(f"{station}: {len(changed)} messages differ, the first {key} #{seq} ({life})")
        elif len(first) != len(second):
            tails.append(f"{station} {len(first)} then {len(second)}")
    if tails or len(csv[0]) != len(csv[1]):
        found.append(
            f"the runs ended on different periods (control.csv {len(csv[0])} then {len(csv[1])} rows; "
            f"sent: {', '.join(tails) or 'alike'})"
        )
    return found, compared


def outcome_line(result: Result) -> str:
    """PASS or FAIL by the scenario's assertions, the run's own verdict as `abyss up` gave it
    (done, incomplete, interrupted, failed; none where the run ended without one), and why it
    failed."""
    verdict = result.run_verdict or "none"
    return f"{'PASS' if result.passed else 'FAIL'} (verdict {verdict}): " + (
        result.why_failed or "every assertion held"
    )


def replay(directory: Path, run_id: str, say: Callable[[str], None]) -> int:
    """Run it again and compare: 0 when it repeats (bit for bit in lockstep, else its verdict)."""
    store = Store(directory)
    spec = find(directory, run_id)
    record = store.records().get(spec.run_id)
    say(
        f"replaying {spec.run_id}: {spec.scenario_name} [{spec.variant.name}] seed {spec.seed}, "
        f"time {spec.time}"
    )
    out = directory / "replays" / f"{spec.run_id}-{len(list(directory.glob(f'replays/{spec.run_id}-*'))) + 1}"
    result = run_scenario(spec.scenario, out, 0, say)
    say(outcome_line(result))
    if record is not None and record.passed != result.passed:
        say(f"the campaign's run {'passed' if record.passed else 'failed'}; this one did not")
    original = directory / record.kept if record is not None and record.kept else None
    if not spec.replayable:
        say(f"not bit for bit: {spec.why_not_replayable}; its failures replay only statistically")
        return 0 if record is None or record.passed == result.passed else 1
    if original is None or not (original / "control.csv").exists():
        say('the campaign kept no directory of this run to compare bytes with (keep = "all" keeps every run)')
        return 0 if record is None or record.passed == result.passed else 1
    found, compared = differences(original, out)
    for line in found:
        say(f"DIFFERS: {line}")
    if not found:
        say(f"byte-identical: control.csv and {compared} messages, to the same last period ({out})")
    return 1 if found or (record is not None and record.passed != result.passed) else 0
