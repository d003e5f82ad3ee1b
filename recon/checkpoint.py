"""Checkpoint files: `checkpoints/latest.pt` and the one before it, `previous.pt` (written by
`Trainer.save_checkpoint`), and reading them back so that one damaged file costs one checkpoint
interval, not the run."""
from __future__ import annotations

from pathlib import Path

import torch

PREVIOUS_CHECKPOINT = "previous.pt"


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
