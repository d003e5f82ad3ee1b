"""thermal4d reconstruction: datasets, Dynamic Thermal Gaussians, rendering, evaluation."""
import os

# libgomp (torch's and the rasterizer's OpenMP) spin-waits 300k iterations between parallel
# regions by default. When another process holds a core -- the capture beside live training --
# the spinning threads starve the working ones: a 50k-Gaussian render + backward took 623 ms
# instead of 168 ms with a short spin (bench note in docs/rasterizer.md). Read once, when torch loads libgomp.
os.environ.setdefault("GOMP_SPINCOUNT", "1000")
