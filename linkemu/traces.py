"""How the shipped delivery traces in config/traces/ were made (mahimahi's format: one 1500-byte
delivery opportunity per line, in whole milliseconds, ascending; the trace repeats), seeded, so
that they can be made again: .venv/bin/python -m abyss.linkemu.traces

- vsat-geo: a geostationary VSAT's 512 kbit/s (the `satellite-geo` profile's rate), each
  opportunity moved by up to 5 ms as a TDMA modem's framing does, 60 s;
- vsat-rain-fade: the same VSAT through a rain fade: 20 s clear, 15 s fading to a tenth, 10 s at
  a tenth, 15 s back, 60 s."""

from pathlib import Path

import numpy as np

TRACES_DIR = Path(__file__).parents[1] / "config" / "traces"  # linkprofile.TRACES_DIR

PERIOD_MS = 1500 * 8 / 512e3 * 1000  # one opportunity at 512 kbit/s: 23.4 ms


def write(name: str, times_ms: np.ndarray) -> None:
    times = np.unique(np.maximum(1, np.round(times_ms).astype(int)))
    (TRACES_DIR / f"{name}.trace").write_text("".join(f"{t}\n" for t in times))
    print(
        f"{name}: {len(times)} opportunities over {times[-1]} ms, {len(times) * 12000 / times[-1]:.0f} kbit/s"
    )


def fade(t_s: float) -> float:
    """The rain fade's share of the clear rate at `t_s`."""
    if t_s < 20.0:
        return 1.0
    if t_s < 35.0:
        return 1.0 - 0.9 * (t_s - 20.0) / 15.0
    if t_s < 45.0:
        return 0.1
    return 0.1 + 0.9 * (t_s - 45.0) / 15.0


def main() -> None:
    rng = np.random.default_rng(40)
    count = int(60000 / PERIOD_MS)
    write("vsat-geo", np.arange(1, count + 1) * PERIOD_MS + rng.uniform(-5.0, 5.0, count))
    times, now_s = [], 0.0
    while now_s < 60.0:
        now_s += PERIOD_MS / 1000.0 / fade(now_s)
        times.append(now_s * 1000.0)
    write("vsat-rain-fade", np.array(times))


if __name__ == "__main__":
    main()
