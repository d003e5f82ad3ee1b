"""How far along its schedule a run is (progress p in [0, 1]), and when it ends.

Every schedule of training (learning-rate decay, routing phases, densification window, SH degree,
coarse-to-fine time rows) is written as a function of p, so its shape holds for any length. Three
ways to drive p:

- a fixed budget: p = iteration / iterations, or elapsed / (60 minutes) with ``minutes``;
- converge (``recon run``'s default): the length is chosen by the scene. p advances one nominal
  step (1 / iterations) per iteration, but *holds* at ``hold_at`` (the end of the free phase:
  routing still learning, densification on) while held-out PSNR still gains ``min_gain_db``
  within ``patience`` evaluations. Once it has converged, p runs on to 1 over the remaining
  (1 - hold_at) * iterations: routing specialises and freezes, learning rates decay, the run ends.
  A wall-clock cap (``minutes``) ends the hold early and, if needed, squeezes the rest so that the
  run ends at the cap;
- live training (recon.live.follow) sets p itself.

p never goes backwards, so no phase is ever revisited.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class Schedule:
    iterations: int                      # nominal length: the run's length without a hold
    minutes: float | None = None         # budget (fixed) or cap (converge)
    converge: bool = False
    hold_at: float = 1 / 3
    patience: int = 4                    # evaluations without a gain of min_gain_db
    min_gain_db: float = 0.1
    min_hold_evals: int = 2              # evaluations before the hold may end
    p: float = 0.0
    holding: bool = False
    released: bool = False
    stop_reason: str | None = None
    best: float = -math.inf
    since_best: int = 0
    evals: int = 0
    history: list = field(default_factory=list)
    marks: list = field(default_factory=list)     # (iteration, elapsed s) every 50 iterations: the recent pace

    # ------------------------------------------------------------------ progress
    def progress(self, iteration: int, elapsed_s: float) -> float:
        if not self.converge:
            if self.minutes:
                return min(elapsed_s / (60.0 * self.minutes), 1.0)
            return min(iteration / max(self.iterations, 1), 1.0)
        return self.p

    def advance(self, iteration: int, elapsed_s: float) -> None:
        """After each iteration (converge mode): move p on unless holding; squeeze the rest of the
        schedule when the cap would be passed."""
        if not self.converge:
            return
        step = 1.0 / max(self.iterations, 1)
        if not self.released and self.p + step >= self.hold_at:
            self.p = max(self.p, self.hold_at - 1e-9)
            self.holding = True
        else:
            self.p = min(self.p + step, 1.0)
        if self.minutes and iteration > 0:
            if iteration % 50 == 0 and (not self.marks or self.marks[-1][0] < iteration):
                self.marks = (self.marks + [(iteration, elapsed_s)])[-6:]    # for the recent pace
            left_s = 60.0 * self.minutes - elapsed_s
            need = self.seconds_to_finish(iteration, elapsed_s)
            if self.holding and not self.released and left_s < need:
                self.release(f"time cap of {self.minutes:g} min: the hold ended to finish the schedule")
            if self.released and left_s > 0 and need > left_s:
                self.p = min(self.p + step * need / left_s, 1.0)   # end at the cap
            if left_s <= 0:
                self.p = 1.0
                self.stop_reason = self.stop_reason or f"time cap of {self.minutes:g} min reached"

    def seconds_to_finish(self, iteration: int, elapsed_s: float) -> float:
        """Wall-clock seconds the rest of the schedule (1 - p) needs at one nominal step per
        iteration, at the recent pace: over the last 250 iterations, not since the start (a
        run's first iterations are slower, e.g. while its time window grows; coarse to fine
        changes the cost per iteration along the run)."""
        i0, e0 = self.marks[0] if self.marks and self.marks[0][0] < iteration else (0, 0.0)
        return (1.0 - self.p) * max(self.iterations, 1) * (elapsed_s - e0) / (iteration - i0)

    def release(self, reason: str) -> None:
        self.holding, self.released = False, True
        self.stop_reason = reason

    # ------------------------------------------------------------------ held-out evaluations
    def observe(self, iteration: int, score_db: float | None) -> None:
        """A held-out PSNR (mean over modalities) measured at this iteration."""
        if score_db is None or not math.isfinite(score_db):
            return
        self.evals += 1
        self.history.append((iteration, round(score_db, 3)))
        if score_db >= self.best + self.min_gain_db:
            self.best, self.since_best = score_db, 0
        else:
            self.since_best += 1
        if (self.converge and self.holding and not self.released and self.evals >= self.min_hold_evals
                and self.since_best >= self.patience):
            self.release(f"converged: held-out PSNR gained less than {self.min_gain_db:g} dB in "
                         f"{self.patience} evaluations (best {self.best:.2f} dB) at iteration {iteration}")

    def done(self, iteration: int, elapsed_s: float) -> bool:
        return self.progress(iteration, elapsed_s) >= 1.0

    def end_reason(self, iteration: int) -> str:
        if not self.converge:
            return (f"budget of {self.minutes:g} min reached" if self.minutes
                    else f"budget of {self.iterations} iterations reached")
        return self.stop_reason or f"schedule of {self.iterations} iterations completed"

    # ------------------------------------------------------------------ checkpoints
    def state(self) -> dict:
        return {k: getattr(self, k) for k in ("p", "holding", "released", "stop_reason", "best",
                                               "since_best", "evals", "history", "marks")}

    def load_state(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, v)
