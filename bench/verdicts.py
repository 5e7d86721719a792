"""Same inputs, same verdict: the scenario library N times at --parallel 2 (default 3). Prints
whether every scenario's verdict and every assertion's outcome were identical across the runs,
and the spread (min / median / max) of each asserted figure, to set bounds from measurements.
Run: .venv/bin/python bench/verdicts.py [--times 3]."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = [p for p in sorted((ROOT / "scenarios").glob("*.toml")) if p.stem != "external-onboard"]
ROW = re.compile(r"^\| `([^`]+)` \| (yes|no) \| (.*) \|$", re.MULTILINE)
NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


def one_run(out: Path) -> tuple[dict[str, str], dict[tuple[str, str], tuple[str, list[float]]]]:
    """Each scenario's verdict word, and each assertion's outcome with the figures in its detail."""
    subprocess.run(
        [
            sys.executable,
            "-P",
            "-m",
            "abyss.cli",
            "scenario",
            "run",
            *map(str, LIBRARY),
            "--parallel",
            "2",
            "--report",
            str(out),
            "--junit",
            str(out / "junit.xml"),
        ],
        capture_output=True,
        cwd=out.parent,
        check=False,
    )
    words = {
        c.get("name", ""): c.find("properties/property[@name='verdict']").get("value", "")  # type: ignore[union-attr]
        for c in ET.parse(out / "junit.xml").getroot().iter("testcase")
    }
    outcomes = {}
    report = (out / "report.md").read_text()
    for section in report.split("\n## ")[1:]:
        name = section.split("\n", 1)[0].strip()
        for assertion, held, detail in ROW.findall(section):
            outcomes[name, assertion] = (held, [float(x) for x in NUMBER.findall(detail)])
    return words, outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--times", type=int, default=3)
    args = parser.parse_args()
    words: list[dict[str, str]] = []
    figures: dict[tuple[str, str], list[list[float]]] = defaultdict(list)
    held: dict[tuple[str, str], set[str]] = defaultdict(set)
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.times):
            print(f"library run {i + 1}/{args.times} ({len(LIBRARY)} scenarios) ...", flush=True)
            w, outcomes = one_run(Path(tmp) / f"run-{i}")
            words.append(w)
            print("  " + ", ".join(f"{n}: {v}" for n, v in sorted(w.items())), flush=True)
            for key, (h, numbers) in outcomes.items():
                held[key].add(h)
                figures[key].append(numbers)
    same_words = all(w == words[0] for w in words)
    unstable = sorted(k for k, h in held.items() if len(h) > 1)
    print(
        f"\nverdicts identical over {args.times} runs: {same_words}; assertions that changed outcome: "
        f"{unstable or 'none'}"
    )
    print("\n| scenario | assertion | held | figures min / median / max |\n| --- | --- | --- | --- |")
    for (name, assertion), runs in sorted(figures.items()):
        width = min(len(r) for r in runs)
        spread = "; ".join(
            f"{min(col):g} / {float(np.median(col)):g} / {max(col):g}"
            for col in ([r[j] for r in runs] for j in range(width))
        )
        print(f"| {name} | `{assertion}` | {'/'.join(sorted(held[name, assertion]))} | {spread} |")


if __name__ == "__main__":
    main()
