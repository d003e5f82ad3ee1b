"""Native extensions. Everything else lives in pyproject.toml.

recon.splat._native, recon.eval._native and recon.dtg._native are built with pybind11 alone: they take numpy buffers,
so building them never needs torch. Flags chosen by measurement on the target CPUs (see README, "splat"):
-O3, OpenMP for tile parallelism, and -march=native for AVX2/FMA (8-lane strips) or AVX-512
(16-lane strips: a whole tile row).
"""
import os

from pybind11.setup_helpers import Pybind11Extension
from setuptools import setup

CSRC = "recon/splat/csrc"
FLAGS = dict(cxx_std=17, extra_compile_args=["-O3", "-fopenmp", "-march=native", "-fno-math-errno"],
             extra_link_args=["-fopenmp"])

native = Pybind11Extension(
    "recon.splat._native",
    sorted(os.path.join(CSRC, f) for f in os.listdir(CSRC) if f.endswith(".cpp")),
    include_dirs=[CSRC],
    depends=sorted(os.path.join(CSRC, f) for f in os.listdir(CSRC)),
    **FLAGS,
)

# SSIM's loss and blur (recon/eval/metrics.py): the training loss's other image-sized kernel.
ssim = Pybind11Extension("recon.eval._native", ["recon/eval/csrc/ssim.cpp"], **FLAGS)

# The rigid bodies' motion (recon/dtg/motion.py): many tiny torch ops fused into one pass.
motion = Pybind11Extension("recon.dtg._native", ["recon/dtg/csrc/motion.cpp"], **FLAGS)

setup(ext_modules=[native, ssim, motion])
