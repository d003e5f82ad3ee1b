"""From a rig session to a prepared dataset: pairing, frame selection, pose recovery (pycolmap),
metric scale, thermal pose transfer through the rig calibration, dataset and report.

    from recon.prepare import prepare_session, PrepareError
    transforms = prepare_session("sessions/s1", "data/s1", frames=80, downscale=2)
"""
from recon.prepare.frames import PrepareError
from recon.prepare.pipeline import REPORT_FILE, PrepareOptions, prepare_session

__all__ = ["PrepareError", "PrepareOptions", "REPORT_FILE", "prepare_session"]
