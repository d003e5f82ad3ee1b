"""How a model is trained: the loop (trainer.py), when a run ends (schedule.py), the growing time
window (curriculum.py), divergence detection and rollback (guard.py), checkpoints (checkpoint.py)."""
