"""Fuzz the CLI with hostile inputs: every run ends in exit 0 or 2, one clean line on error, no NaN out.

For each of ``estimate``, ``diagnose``, ``features`` and ``batch``, a seeded generator makes at least
:data:`CASES` inputs from the hardening issue's table and beyond: dtypes (float16/32/64, int8/16/32/64,
uint8/16, bool, complex), shapes (1-D, 2-D, 4-D, empty, one frame, tiny, up to 32 x 32 x 20; diagnose's
few full runs at 28 x 28 x 24 to bound its cost), values (NaN, infinities, 1e3 to 1e300 samples,
constant, all NaN, time-reversed, huge offsets), spacings (in the file, missing, zero, negative,
non-finite, tiny, huge; as flags or in the file), random bytes, truncated files.
Each run calls :func:`anra_torch.cli.main` in this process and checks:

- the exit status is 0 or 2 (1 would be an internal error, a bug);
- stderr has no traceback and no Python warning, and on exit 2 it is one ``anra: error:`` line;
- every JSON line on stdout parses with NaN and infinities refused; every CSV cell of ``batch`` is empty,
  text or a finite number; no "nan" or "inf" word anywhere in the output.

hypothesis is not installed in this environment, so the cases come from ``numpy.random.default_rng``
(the same seed gives the same cases; a failure names its case index and arguments).
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from commands import ECHOED_NON_FINITE, NON_FINITE_WORD, assert_clean, run_isolated

pytestmark = pytest.mark.slow

CASES = 300
"""Inputs per subcommand (batch: inputs over all its runs)."""

_DTYPES = ("float64", "float32", "float16", "int16", "uint8", "uint16", "int32", "int64", "int8")
_SPACINGS = (0.04, 0.1, 0.5, 1e-6, 1e6, 0.0, -1.0, math.nan, math.inf, 1e-300, 1e300, 0.0001)
_FLAGS = ("0.04", "0.2", "0", "-1", "nan", "inf", "1e-300", "1e300", "abc", "0.0001", "1e6", "1e-7")
_SPIKES = (1e3, 1e4, 1e6, 2e6, 1e15, 1e20, 1e30, 1e300, -1e300, math.inf, -math.inf, math.nan)


def _smooth(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """A diffusing Gaussian spot (the physics the commands look for) with noise, of any shape."""
    if len(shape) != 3 or min(shape) == 0:
        return rng.standard_normal(shape)
    t, h, w = shape
    y, x = np.mgrid[:h, :w]
    spread = 2.0 + 0.3 * np.arange(t)[:, None, None]
    spot = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2)[None] / (2 * spread**2)) / spread**2
    return 30 + 160 * spot + rng.choice([0.0, 0.01, 0.3]) * rng.standard_normal(shape)


def _shape(rng: np.random.Generator, command: str) -> tuple[int, ...]:
    """Mostly tiny videos; diagnose runs the full pipeline only on a few (it costs ~2 s each)."""
    kind = rng.choice(["3d"] * 16 + ["1d", "2d", "4d", "empty"])
    if kind == "1d":
        return (int(rng.integers(0, 30)),)
    if kind == "2d":
        return (int(rng.integers(1, 20)), int(rng.integers(1, 20)))
    if kind == "4d":
        return (2, 6, 8, 8)
    if kind == "empty":
        return tuple(int(v) for v in rng.permutation([0, 5, 6]))
    big = rng.random() < (0.1 if command == "diagnose" else 0.7)
    sides = ((28,) if command == "diagnose" else (24, 28, 32)) if big else (1, 2, 3, 5, 8, 12, 16)
    frames = ((24,) if command == "diagnose" else (12, 16, 20)) if big else (1, 2, 3, 5, 8, 12, 20)
    return int(rng.choice(frames)), int(rng.choice(sides)), int(rng.choice(sides))


def _corrupt(rng: np.random.Generator, values: np.ndarray) -> np.ndarray:
    """Apply one of the issue's value problems (or none) to float64 ``values``."""
    if values.size == 0:
        return values
    what = rng.choice(
        ["none"] * 4 + ["spike"] * 3 + ["spikes", "nan_some", "nan_all", "const", "reverse", "scale"]
    )
    flat = values.reshape(-1)
    if what == "spike":
        flat[rng.integers(flat.size)] = rng.choice(_SPIKES)
    elif what == "spikes":
        index = rng.choice(flat.size, size=max(1, flat.size // int(rng.choice([2, 10, 100]))), replace=False)
        flat[index] = rng.choice(_SPIKES)
    elif what == "nan_some":
        flat[rng.random(flat.size) < rng.choice([0.01, 0.04, 0.2, 0.9])] = np.nan
    elif what == "nan_all":
        flat[:] = np.nan
    elif what == "const":
        flat[:] = rng.choice([0.0, 37.0, 1e5])
    elif what == "reverse" and values.ndim >= 1:
        values = values[::-1].copy()
    elif what == "scale":
        values = values * rng.choice([1e-9, 1e-3, 1e3, 1e8]) + rng.choice([0.0, 300.0, 2e4])
    return values


def _cast(rng: np.random.Generator, values: np.ndarray) -> np.ndarray:
    kind = str(rng.choice(("float64", "float32") * 4 + _DTYPES + ("bool", "complex64")))
    with np.errstate(all="ignore"):
        if kind in ("bool", "complex64"):
            return values.astype(kind)
        if kind.startswith(("int", "uint")):
            info = np.iinfo(kind)
            return np.clip(np.nan_to_num(values, nan=0.0), info.min, info.max).astype(kind)
        return values.astype(kind)


def _write(rng: np.random.Generator, folder: Path, name: str, command: str) -> Path:
    """One input file: an .npz (sometimes .npy, random bytes or truncated) with random frames and spacing."""
    form = rng.choice(["npz"] * 24 + ["npy", "bytes", "truncated", "nofile"])
    path = folder / f"{name}.{'npy' if form == 'npy' else 'npz'}"
    if form == "bytes":
        path.write_bytes(rng.bytes(int(rng.integers(0, 3000))))
        return path
    if form == "nofile":
        return path
    frames = _cast(rng, _corrupt(rng, _smooth(rng, _shape(rng, command))))
    if form == "npy":
        np.save(path, frames)
        return path
    arrays: dict[str, object] = {"frames": frames}
    for key in ("dt", "dx"):
        if rng.random() < 0.92:
            arrays[key] = rng.choice(_SPACINGS) if rng.random() < 0.15 else (0.04 if key == "dt" else 0.1)
    np.savez(path, **arrays)
    if form == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: int(rng.integers(0, len(data)))])
    return path


def _flags(rng: np.random.Generator, command: str) -> list[str]:
    argv = []
    for flag in ("--dt", "--dx"):
        if rng.random() < 0.12:
            argv += [flag, str(rng.choice(_FLAGS))]
    if rng.random() < 0.1:
        argv.append("--roi=" + str(rng.choice(["0,0,20,20", "2,2,30,30", "0,0,1,1", "a,b", "-1,0,4,4"])))
    if command == "estimate" and rng.random() < 0.1:
        argv += [
            "--window",
            str(rng.choice(["1", "3", "5", "4"])),
            *(["--mode", "ratio"] * (rng.random() < 0.3)),
        ]
    if command == "diagnose" and rng.random() < 0.1:
        argv += ["--fit-fraction", str(rng.choice(["0.5", "0.9", "1", "0"]))]
    if command == "features" and rng.random() < 0.2:
        argv += ["--units", "K"]
    return argv


def _check_table(label: str, table: Path) -> int:
    """Every cell of a batch CSV is empty, text or finite; returns the number of rows with status ok."""
    if not table.exists():
        return 0
    with table.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        for key, cell in row.items():
            assert not NON_FINITE_WORD.fullmatch(cell.strip()), f"{label}: non-finite {key}={cell!r}"
            assert not NON_FINITE_WORD.search(ECHOED_NON_FINITE.sub("", cell)), (
                f"{label}: non-finite word in {key}={cell!r}"
            )
    return sum(row["status"] == "ok" for row in rows)


def _fuzz(command: str, seed: int, tmp_path: Path, make_argv: Callable[..., tuple[list[str], int]]) -> dict:
    rng = np.random.default_rng(seed)
    codes = {0: 0, 2: 0}
    inputs = index = ok_rows = 0
    start = time.perf_counter()
    while inputs < CASES:
        folder = tmp_path / f"case{index}"
        folder.mkdir()
        argv, n = make_argv(rng, folder, index)
        label = f"{command} case {index}: {' '.join(argv)}"
        code, out, err, caught = run_isolated(argv)
        assert_clean(label, code, out, err, caught)
        if command == "batch":
            ok_rows += _check_table(label, folder / "rows.csv")
        codes[code] += 1
        inputs += n
        index += 1
    seconds = time.perf_counter() - start
    return {"runs": index, "inputs": inputs, "codes": codes, "ok_rows": ok_rows, "seconds": round(seconds, 1)}


def _single(command: str) -> Callable[..., tuple[list[str], int]]:
    def make(rng: np.random.Generator, folder: Path, index: int) -> tuple[list[str], int]:
        path = _write(rng, folder, f"v{index}", command)
        json_flag = ["--json"] if rng.random() < 0.7 else []
        return [command, str(path), *_flags(rng, command), *json_flag], 1

    return make


def _batch(rng: np.random.Generator, folder: Path, index: int) -> tuple[list[str], int]:
    n = int(rng.integers(1, 13))
    paths = [str(_write(rng, folder, f"v{k}", "batch")) for k in range(n)]
    extra = _flags(rng, "batch")
    if rng.random() < 0.3:
        extra.append("--float64")
    if rng.random() < 0.03:  # the full diagnosis: a few runs only (seconds each)
        extra.append("--diagnose")
    json_flag = ["--json"] if rng.random() < 0.5 else []
    return ["batch", *paths, "--out", str(folder / "rows.csv"), "--no-progress", *extra, *json_flag], n


@pytest.mark.parametrize(
    ("command", "seed"), [("estimate", 1), ("diagnose", 2), ("features", 3), ("batch", 4)]
)
def test_fuzzed_inputs_end_in_exit_0_or_2_with_clean_output(command: str, seed: int, tmp_path: Path) -> None:
    make = _batch if command == "batch" else _single(command)
    stats = _fuzz(command, seed, tmp_path, make)
    print(f"fuzz {command}: {stats}")
    assert stats["inputs"] >= CASES
    # both outcomes are exercised: real results and refusals
    assert stats["codes"][0] > 0 and stats["codes"][2] > 0
