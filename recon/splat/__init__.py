"""Native, differentiable, multi-threaded CPU Gaussian rasterizer (3DGS math).

Entry point: `rasterization(...) -> RenderOutput`; see recon/splat/rasterization.py.
"""
from recon.splat.rasterization import RenderOutput, rasterization

__all__ = ["RenderOutput", "rasterization"]
