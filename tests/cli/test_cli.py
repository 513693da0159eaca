"""The ``anra`` command line as a whole (:mod:`anra_torch.cli`): one-line errors and exit 2 for bad input of
every command, help texts with units, thread counts.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from commands import assert_one_line_error, run
from shared_data import DATA, needs_data

from anra_torch.cli import _parser, build_parser, main


# --------------------------------------------------------------------------------------------- errors
def _bad_files(tmp: Path, paper96: Path) -> dict[str, tuple[list[object], str]]:
    frames = np.zeros((8, 16, 16))
    np.save(tmp / "raw.npy", frames)
    np.savez(tmp / "noframes.npz", video=frames, dt=0.1)
    np.savez(tmp / "flat2d.npz", frames=frames[0], dt=0.1, dx=0.1)
    np.savez(tmp / "nodx.npz", frames=frames, dt=0.1)
    np.savez(tmp / "short.npz", frames=frames[:3], dt=0.1, dx=0.1)
    (tmp / "trunc.npz").write_bytes(paper96.read_bytes()[:5000])
    (tmp / "clip.avi").write_bytes(b"RIFF")
    return {
        "missing file": (["estimate", tmp / "none.npz"], r"none\.npz: no such file"),
        "unknown suffix": (
            ["estimate", tmp / "clip.avi"],
            r"unknown video format '\.avi'; expected one of: .*\.npz",
        ),
        "npy without dt": (["estimate", tmp / "raw.npy"], r"raw\.npy: no frame period: .*--dt"),
        "npy without dx": (
            ["estimate", tmp / "raw.npy", "--dt", "0.1"],
            r"raw\.npy: no pixel size: .*--dx in mm",
        ),
        "npz without dx": (["estimate", tmp / "nodx.npz"], r"nodx\.npz: no pixel size"),
        "no frames": (["estimate", tmp / "noframes.npz"], r"noframes\.npz: no 'frames' array"),
        "wrong ndim": (
            ["estimate", tmp / "flat2d.npz"],
            r"frames must have shape \(T, H, W\), got \(16, 16\)",
        ),
        "too few frames": (["estimate", tmp / "short.npz"], r"short\.npz: .*at least 5 frames"),
        "truncated": (
            ["estimate", tmp / "trunc.npz"],
            r"trunc\.npz: cannot read as \.npz .*truncated or corrupt",
        ),
        "negative dt": (
            ["estimate", paper96, "--dt", "-1"],
            r"argument --dt: must be a positive number in s",
        ),
        "text dx": (["estimate", paper96, "--dx", "wide"], r"argument --dx: must be a positive number in mm"),
        "even window": (
            ["estimate", paper96, "--window", "14"],
            r"argument --window: must be an odd integer",
        ),
        "unknown mode": (["estimate", paper96, "--mode", "fast"], r"argument --mode: invalid choice: 'fast'"),
        "no command": ([], r"required: COMMAND \(see 'anra --help'\)"),
        "unknown command": (["fit"], r"invalid choice: 'fit'"),
        "frames and duration": (
            ["simulate", "--frames", "5", "--duration", "1", "-o", tmp / "x.npz"],
            r"argument --duration: not allowed with argument --frames",
        ),
        "no output": (["simulate"], r"required: -o/--out"),
        "crop too large": (
            ["simulate", "--size", "32", "--crop", "64", "-o", tmp / "x.npz"],
            r"--crop must be at",
        ),
        "negative noise": (["simulate", "--noise", "-1", "-o", tmp / "x.npz"], r"non-negative number"),
    }


BAD_CASES = [
    "missing file",
    "unknown suffix",
    "npy without dt",
    "npy without dx",
    "npz without dx",
    "no frames",
    "wrong ndim",
    "too few frames",
    "truncated",
    "negative dt",
    "text dx",
    "even window",
    "unknown mode",
    "no command",
    "unknown command",
    "frames and duration",
    "no output",
    "crop too large",
    "negative noise",
]


@pytest.mark.parametrize("case", BAD_CASES)
def test_bad_input_gives_one_line_error_and_exit_2(
    case: str, paper96: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = _bad_files(tmp_path, paper96)
    assert set(cases) == set(BAD_CASES)
    argv, match = cases[case]
    assert_one_line_error(run(capsys, *argv), match)
    assert not (tmp_path / "x.npz").exists()


def test_help_texts_state_units(capsys: pytest.CaptureFixture[str]) -> None:
    for command, units in {
        (): ("mm^2/s", "mm,", " s,"),
        ("estimate",): ("in s", "in mm", "mm^2/s", "(T, H, W)"),
        ("simulate",): ("mm^2/s", "Hz", "in mm", "in px", "in s"),
        ("demo",): ("mm^2/s", "mm", "Hz"),
    }.items():
        code, out, err = run(capsys, *command, "--help")
        assert (code, err) == (0, "")
        text = " ".join(out.split())
        for unit in units:
            assert unit in text, (command, unit)


def test_threads_option_sets_torch_threads(paper96: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = torch.get_num_threads()
    try:
        assert main(["--threads", "1", "estimate", str(paper96), "--json"]) == 0
        assert torch.get_num_threads() == 1
        assert json.loads(capsys.readouterr().out)["diffusivity"] == pytest.approx(0.2, rel=0.01)
        assert main(["--threads", "0", "estimate", str(paper96)]) == 2
        assert "argument --threads: must be an integer >= 1" in capsys.readouterr().err
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize(("running", "expected"), [(1, 4), (2, 3), (4, 1), (9, 1)])
def test_default_threads_leave_the_cores_other_processes_run_on(
    tmp_path: Path, running: int, expected: int
) -> None:
    from anra_torch.cli import free_cores

    loadavg = tmp_path / "loadavg"
    loadavg.write_text(f"3.93 4.27 4.78 {running}/88 20791\n")  # the runnable count includes this process
    assert free_cores(4, loadavg) == expected
    assert free_cores(4, tmp_path / "absent") == 4


def test_the_default_thread_count_does_not_shrink_call_after_call(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The free-core default starts from the process's own count each time, not from the last command's."""
    import anra_torch.cli as cli

    bases: list[int] = []
    monkeypatch.setattr(cli, "free_cores", lambda cores: bases.append(cores) or max(1, cores - 1))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(4)  # each call's default then sets fewer
        for seed in range(3):
            argv = ["simulate", "--size", "16", "--frames", "8", "--seed", str(seed)]
            assert main([*argv, "-o", str(tmp_path / f"v{seed}.npz")]) == 0
    finally:
        torch.set_num_threads(before)
    assert len(bases) == 3 and len(set(bases)) == 1


def test_only_the_command_freezes_what_its_imports_built(monkeypatch: pytest.MonkeyPatch) -> None:
    """A process running ``anra`` (argv from ``sys.argv``) freezes its imports' objects out of the garbage
    collector's passes and keeps its freed memory; a caller passing ``argv`` (a library user, the tests)
    keeps its collector and allocator as they are."""
    import anra_torch.cli as cli

    frozen: list[str] = []
    monkeypatch.setattr(cli.gc, "freeze", lambda: frozen.append("gc"))
    monkeypatch.setattr(cli, "_keep_freed_memory", lambda: frozen.append("malloc"))
    assert main(["--version"]) == 0
    assert not frozen
    monkeypatch.setattr(cli.sys, "argv", ["anra", "--version"])
    assert main() == 0
    assert frozen == ["gc", "malloc"]
    monkeypatch.undo()

    def no_glibc(name: str) -> None:
        raise OSError(f"{name}: cannot open shared object file")

    monkeypatch.setattr(cli.ctypes, "CDLL", no_glibc)
    cli._keep_freed_memory()  # another C library: nothing changes, nothing raised


@needs_data
def test_cli_one_line_errors_on_real_files(capsys: pytest.CaptureFixture[str]) -> None:
    csv = DATA / "flir_csv" / "Sample2 RT M1.csv"
    assert main(["estimate", str(csv), "--dt", "0.1", "--dx", "0.25", "--calibration", str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected 'true,apparent'" in err
    assert main(["diagnose", str(csv), "--dx", "0.25"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no frame period" in err


def test_the_parser_main_reuses_parses_each_call_as_a_fresh_one() -> None:
    """main() builds its parser once per process: a repeatable option given in one call must not reach the
    next, and every call's namespace equals a freshly built parser's."""
    once = ["simulate", "--out", "x.npy", "--effect", "advection", "--param", "advection.vx=0.5"]
    plain = ["simulate", "--out", "x.npy"]
    assert _parser() is _parser()
    first = vars(_parser().parse_args(once))
    second = vars(_parser().parse_args(plain))
    assert second["effect"] is None and second["param"] is None
    assert first == vars(build_parser().parse_args(once))
    assert second == vars(build_parser().parse_args(plain))
