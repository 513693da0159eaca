"""Two runs of ``diagnosis_benchmark.py`` case by case: the same names, the same gains, and the time.

Matches the cases of two ``results.json`` files by group and index (the cases are seeded, so the same
group and index is the same video) and prints how many name the same effects, how many have the same
forecast gain to 2 decimals, the cases that differ, and the median diagnosis time per case (per group and
overall) of each run.

    python -m benchmarks.compare_benchmarks BEFORE/results.json AFTER/results.json
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def _records(path: Path) -> dict[tuple[str, int], dict]:
    return {(r["group"], r["index"]): r for r in json.loads(path.read_text())["records"]}


def _same_gain(before: float | None, after: float | None) -> bool:
    if before is None or after is None:
        return before is None and after is None
    return round(before, 2) == round(after, 2)


def compare(before: dict[tuple[str, int], dict], after: dict[tuple[str, int], dict]) -> str:
    """The comparison as Markdown lines (cases present in both runs only)."""
    common = sorted(set(before) & set(after))
    names = sum(before[k].get("found") == after[k].get("found") for k in common)
    gains = sum(_same_gain(before[k].get("gain"), after[k].get("gain")) for k in common)
    lines = [f"{len(common)} cases in both runs: same names {names}, same gain to 2 decimals {gains}", ""]
    for k in common:
        b, a = before[k], after[k]
        if b.get("found") != a.get("found") or not _same_gain(b.get("gain"), a.get("gain")):
            was, now = f"{b.get('found')} gain {b.get('gain')}", f"{a.get('found')} gain {a.get('gain')}"
            lines.append(f"- differs: {k[0]} {k[1]}: {was} -> {now}")
    lines += ["| group | median s before | median s after | after / before |", "|---|---|---|---|"]
    groups = sorted({k[0] for k in common}, key=[k[0] for k in common].index)
    for group in [*groups, "all"]:
        keys = [k for k in common if group in (k[0], "all")]
        t_b = statistics.median(before[k]["seconds"] for k in keys)
        t_a = statistics.median(after[k]["seconds"] for k in keys)
        lines.append(f"| {group} | {t_b:.2f} | {t_a:.2f} | {t_a / t_b:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("before", type=Path, help="results.json of the earlier run")
    parser.add_argument("after", type=Path, help="results.json of the later run")
    args = parser.parse_args()
    print(compare(_records(args.before), _records(args.after)))


if __name__ == "__main__":
    main()
