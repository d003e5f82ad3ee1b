"""thermal4d reconstruction: datasets, Dynamic Thermal Gaussians, rendering, evaluation."""
import os

# libgomp (torch's and the rasterizer's OpenMP) spin-waits GOMP_SPINCOUNT iterations before an
# idle worker thread sleeps; it reads the variable once, when torch loads libgomp, so this must run
# before the first `import torch` (import recon first). The default, 300k, starves the working
# thread when another process holds a core (the capture beside live training: a 160x120 step 580
# ms instead of 39 ms with one core busy); too short a spin puts the worker to sleep between
# torch's many small parallel regions, and waking it costs more than the region (idle 2-core
# machine, trained 160x120 model: 28.0 ms a step at 1000, 23.1 at 3000, 20.4 at 300k; 640x480
# windows 88 / 73 / 69 ms). 3000 keeps most of the idle speed and, with one core busy, costs 44
# against 39 ms (docs/rasterizer.md, "Wait policy").
os.environ.setdefault("GOMP_SPINCOUNT", "3000")
