"""What a batch is made of: jobs (input x method x seed), their folders under RUNS, and the state
files that say what each one has done (contract: recon/batch/__init__.py)."""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

FORMAT, VERSION = "thermal4d-batch", 1


@dataclass
class Job:
    """One run of the batch. `spec` is what the executing function needs beyond the name
    (for `recon batch`: recon run's options; bench/table.py puts its own grid point there)."""
    name: str                       # also the run folder, relative to RUNS
    input: str
    method: str
    seed: int | None
    threads: int = 1
    spec: dict = field(default_factory=dict)

    def run_dir(self, runs: Path) -> Path:
        return runs / self.name

    def as_dict(self) -> dict:
        return asdict(self)


def expand(inputs: list[Path], methods: list[str], seeds: list[int] | None, threads: int,
           spec: dict | None = None) -> list[Job]:
    """Every (input, method, seed), named INPUT/METHOD or INPUT/METHOD-sSEED. Two inputs with
    the same folder name would share run folders: refused."""
    names: dict[str, Path] = {}
    for path in inputs:
        key = path.resolve().name
        if key in names:
            raise ValueError(f"{path}: two inputs are named {key!r} ({names[key]} and {path}); their runs "
                             f"would share RUNS/{key}/: rename or link one of them")
        names[key] = path
    jobs = []
    for key, path in names.items():
        for method in methods:
            for seed in seeds or [None]:
                name = f"{key}/{method}" + (f"-s{seed}" if seed is not None else "")
                jobs.append(Job(name, str(path), method, seed, threads, dict(spec or {})))
    return jobs


def parse_seeds(text: str) -> list[int]:
    """'0-3,7' -> [0, 1, 2, 3, 7]"""
    out = []
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        try:
            out += list(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            raise ValueError(f"--seeds {text!r}: expected numbers and ranges such as 0-3,7") from None
    return out


def read_json(path: Path) -> dict | None:
    """A JSON object, or None if the file is missing or unreadable (a torn write cannot happen,
    but a hand-edited or foreign file can)."""
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def finished(run_dir: Path) -> bool:
    """A job is finished when its run folder holds metrics.json and job.json says done."""
    state = read_json(run_dir / "job.json") or {}
    return state.get("state") == "done" and (run_dir / "metrics.json").exists()


def has_checkpoint(run_dir: Path) -> bool:
    return (run_dir / "checkpoints" / "latest.pt").exists()
