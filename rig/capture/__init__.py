"""`rig capture`: record a session from the thermal camera, the phone drop folder and the sync box.

config.py (what to record), devices.py (opening and closing the devices, real or simulated),
streams.py (the threads that move data from each device into the session), progress.py (the
status line), session_capture.py (`Capture`: runs them for the duration and finishes the session),
cli.py (the command)."""
