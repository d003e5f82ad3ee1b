"""Prepared datasets (shared/FORMATS.md): load, validate, write, and simulate.

    from recon.data import load_dataset, write_dataset, Dataset, Frame, DatasetError
    ds = load_dataset("data/sim")
    for frame in ds.split("thermal", "train"):
        kelvin = ds.image(frame)        # float32 (H, W), NaN = no measurement
        viewmat = frame.viewmat()       # (4, 4) float32 world-to-camera, OpenCV axes
"""
from recon.data.dataset import Dataset, load_dataset
from recon.data.errors import DatasetError
from recon.data.frame import Distortion, Frame, c2w_opencv_to_opengl, viewmat_from_c2w_opengl
from recon.data.writer import write_dataset

__all__ = ["Dataset", "DatasetError", "Distortion", "Frame", "c2w_opencv_to_opengl",
           "load_dataset", "viewmat_from_c2w_opengl", "write_dataset"]
