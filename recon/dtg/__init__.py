"""The Dynamic Thermal Gaussians model (DTG paper, section 3): Gaussians with shared geometry and
per-modality appearance (gaussians.py), their motion (motion.py: rigid bodies; deformation.py and
time_embedding.py: E-D3DGS's networks), routing into shared / rgb-only / thermal-only
(routing.py), densification (strategy.py), priors and losses, and the start from SfM points
(points.py). model.py puts them together: the Gaussians of one modality at a time t."""
