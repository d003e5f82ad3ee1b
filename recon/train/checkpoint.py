"""Checkpoint files: `checkpoints/latest.pt` and the one before it, `previous.pt` (written by
`write_checkpoint`), and reading them back so that one damaged file costs one checkpoint
interval, not the run."""
from __future__ import annotations

from pathlib import Path

import torch

PREVIOUS_CHECKPOINT = "previous.pt"


def write_checkpoint(state: dict, path: Path) -> None:
    """Write `state` to `path` atomically (a crash never leaves a torn checkpoint), keeping the one
    before as previous.pt: a file damaged later still leaves a good state."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    if path.exists():
        path.replace(path.with_name(PREVIOUS_CHECKPOINT))
    tmp.replace(path)


class CheckpointError(RuntimeError):
    """No readable checkpoint; the message names the files and what to do."""


def read_checkpoint(path: Path, log=print) -> tuple[dict, Path]:
    """The state in checkpoint `path`, or, when it is missing or unreadable (a torn copy, a full
    disk), in the previous one beside it (said through `log`). -> (state, the file used)"""
    problems = []
    for candidate in dict.fromkeys((path, path.with_name(PREVIOUS_CHECKPOINT))):
        if not candidate.exists():
            problems.append(f"{candidate}: missing")
            continue
        try:
            state = torch.load(candidate, weights_only=False)
            if not isinstance(state, dict) or "model" not in state or "config" not in state:
                raise ValueError("not a thermal4d checkpoint")
        except Exception as exc:      # torch reports a torn zip, pickle a truncated stream
            problems.append(f"{candidate}: unreadable ({str(exc).split('.')[0]})")
            continue
        if problems:
            log(f"{problems[0]}; using the previous checkpoint {candidate} (iteration {state.get('iteration')})")
        return state, candidate
    raise CheckpointError("; ".join(problems) + ". No usable checkpoint: train again without --resume")
