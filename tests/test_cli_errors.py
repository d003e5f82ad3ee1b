"""No tracebacks on user input: every CLI turns a bad input into one line that names the file or
value, exit code 2; `--debug` shows the traceback; `--resume` falls back to the previous good
checkpoint. The commands run as a user runs them (subprocesses of `python -m recon` / `-m rig`)."""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ENV_THREADS = {"OMP_NUM_THREADS": "1"}


def cli(*argv, cwd: Path) -> subprocess.CompletedProcess:
    import os
    return subprocess.run([sys.executable, "-m", *map(str, argv)], cwd=cwd, capture_output=True, text=True,
                          timeout=300, env={**os.environ, **ENV_THREADS})


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A tiny dataset `ds` and a run `run` trained on it with two checkpoints (latest, previous)."""
    root = tmp_path_factory.mktemp("cli_errors")
    assert cli("recon", "simulate", "ds", "--size", "48x36", "--frames", "6", cwd=root).returncode == 0
    assert cli("recon", "run", "ds", "--out", "run", "--iterations", "20", cwd=root).returncode == 0
    resumed = cli("recon", "run", "ds", "--out", "run", "--resume", "--iterations", "30", cwd=root)
    assert resumed.returncode == 0, resumed.stderr
    assert (root / "run/checkpoints/previous.pt").is_file()
    return root


def broken_copy(work: Path, name: str, damage) -> str:
    shutil.copytree(work / "ds", work / name)
    damage(work / name)
    return name


def first_image(ds: Path) -> Path:
    return ds / json.loads((ds / "transforms.json").read_text())["frames"][0]["file_path"]


def set_first_focal(ds: Path, value: float) -> None:
    meta = json.loads((ds / "transforms.json").read_text())
    frame = meta["frames"][0]
    (frame if "fl_x" in frame else meta)["fl_x"] = value
    (ds / "transforms.json").write_text(json.dumps(meta))


def truncate(path: Path, keep: int = 1000) -> None:
    path.write_bytes(path.read_bytes()[:keep])


def assert_one_clean_line(proc: subprocess.CompletedProcess, *names: str, code: int = 2) -> None:
    """One line (besides progress bars and argparse's usage block) naming each of `names`."""
    lines = [line for line in proc.stderr.splitlines()
             if line.strip() and not line.startswith(("[", "usage:", " "))]
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 1, proc.stderr
    for name in names:
        assert name in lines[0], (name, lines[0])


CASES = {
    "malformed transforms.json": (
        lambda w: broken_copy(w, "bad_json", lambda d: (d / "transforms.json").write_text("{ not json")),
        lambda name: ("recon", "run", name, "--out", f"r_{name}", "--iterations", "5"), "transforms.json"),
    "fl_x 0 in the first frame": (
        lambda w: broken_copy(w, "fl0", lambda d: set_first_focal(d, 0)),
        lambda name: ("recon", "run", name, "--out", f"r_{name}", "--iterations", "5"), "focal"),
    "empty first image": (
        lambda w: broken_copy(w, "empty_img", lambda d: first_image(d).write_bytes(b"")),
        lambda name: ("recon", "run", name, "--out", f"r_{name}", "--iterations", "5"), "000000"),
    "text as an image": (
        lambda w: broken_copy(w, "text_img", lambda d: first_image(d).write_text("hello")),
        lambda name: ("recon", "eval", "run", name), "000000"),
    "a missing path": (
        lambda w: "nowhere",
        lambda name: ("recon", "run", name, "--out", "r_nowhere", "--iterations", "5"), "nowhere"),
    "a folder that is neither dataset nor session": (
        lambda w: (w / "empty_dir").mkdir() or "empty_dir",
        lambda name: ("recon", "run", name, "--out", "r_empty", "--iterations", "5"), "empty_dir"),
    "--iterations 0": (
        lambda w: "ds", lambda name: ("recon", "run", name, "--out", "r_zero", "--iterations", "0"), "--iterations"),
    "negative --minutes": (
        lambda w: "ds", lambda name: ("recon", "run", name, "--out", "r_neg", "--minutes", "-1"), "--minutes"),
    "render without a checkpoint": (
        lambda w: "ds", lambda name: ("recon", "render", name, "--time", "0.5", "--out", "novel"), "checkpoints"),
    "render with a bad pose": (
        lambda w: "run", lambda name: ("recon", "render", name, "--time", "0.5", "--pose", "[1, 2]", "--out", "n"),
        "4x4"),
    "rig info on a dataset": (
        lambda w: "ds", lambda name: ("rig", "info", name), "session.json"),
    "rig info on a damaged session.json": (
        lambda w: (w / "sess").mkdir() or (w / "sess/session.json").write_text("{bad") and "sess",
        lambda name: ("rig", "info", name), "sess/session.json"),
}
# `recon prepare` documents exit 1 for a refusal (with its report written), 2 for bad arguments
PREPARE_REFUSAL = (lambda w: "ds", lambda name: ("recon", "prepare", name, "prep_out"), "session.json")


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_naming_it(work, case):
    make, argv, expected = CASES[case]
    name = make(work)
    assert_one_clean_line(cli(*argv(name), cwd=work), expected)


def test_prepare_refuses_a_dataset_in_one_line(work):
    make, argv, expected = PREPARE_REFUSAL
    assert_one_clean_line(cli(*argv(make(work)), cwd=work), expected, code=1)


def test_debug_shows_the_traceback(work):
    shutil.copytree(work / "ds", work / "dbg")
    (work / "dbg/transforms.json").write_text("{ not json")
    proc = cli("recon", "run", "dbg", "--out", "r_dbg", "--iterations", "5", "--debug", cwd=work)
    assert proc.returncode != 0 and "Traceback" in proc.stderr and "transforms.json" in proc.stderr


def test_a_truncated_checkpoint_falls_back_to_the_previous_one(work):
    shutil.copytree(work / "run", work / "run_torn")
    truncate(work / "run_torn/checkpoints/latest.pt")
    proc = cli("recon", "run", "ds", "--out", "run_torn", "--resume", "--iterations", "35", cwd=work)
    assert proc.returncode == 0, proc.stderr
    said = proc.stdout + proc.stderr
    assert "latest.pt: unreadable" in said and "using the previous checkpoint" in said
    assert "resumed at iteration 20" in said          # previous.pt held iteration 20, latest 30
    rendered = cli("recon", "render", "run_torn", "--time", "0.5", "--out", "novel_torn", cwd=work)
    assert rendered.returncode == 0, rendered.stderr


def test_no_good_checkpoint_left_is_one_line(work):
    shutil.copytree(work / "run", work / "run_gone")
    for name in ("latest.pt", "previous.pt"):
        truncate(work / "run_gone/checkpoints" / name, 200)
    proc = cli("recon", "render", "run_gone", "--time", "0.5", "--out", "novel_gone", cwd=work)
    assert_one_clean_line(proc, "latest.pt", "previous.pt")
