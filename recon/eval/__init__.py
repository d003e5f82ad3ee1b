"""Evaluation: PSNR, SSIM (3DGS convention, differentiable), thermal MAE in kelvin, LPIPS.

    from recon.eval import psnr, ssim, thermal_mae_k, Lpips, evaluate_run, write_render
"""
from recon.eval.evaluate import evaluate_run, markdown_table, write_results
from recon.eval.lpips import Lpips
from recon.eval.metrics import psnr, ssim, ssim_map, thermal_mae_k
from recon.eval.renders import RenderError, read_render, render_path, write_render

__all__ = ["Lpips", "RenderError", "evaluate_run", "markdown_table", "psnr", "read_render",
           "render_path", "ssim", "ssim_map", "thermal_mae_k", "write_render", "write_results"]
