"""Training while the capture runs: follow a growing session (follow.py) and publish progress for
the status page (publish.py)."""
