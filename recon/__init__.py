"""thermal4d reconstruction: datasets, Dynamic Thermal Gaussians, rendering, evaluation."""
import os

# libgomp (torch's and the rasterizer's OpenMP) spin-waits GOMP_SPINCOUNT iterations before an
# idle worker thread sleeps; it reads the variable once, when torch loads libgomp, so this must run
# before the first `import torch` (import recon first). Too short a spin puts the worker to sleep
# between torch's many small parallel regions, and waking it costs more than the region (idle
# 2-core machine, trained 160x120 model: 28.0 ms a step at 1000, 23.1 at 3000, 21.5 at 30k, 20.4
# at libgomp's default 300k). A long spin starves the working thread when another process holds a
# core (with one core busy: 39 ms at 1000, 44 at 3000, 135 at 30k, 580 at 300k), which training
# avoids by dropping to one thread then (recon/train/cores.py: 29 ms); 30k bounds the cost for
# whatever else runs two threads beside a busy core (docs/rasterizer.md, "Wait policy").
os.environ.setdefault("GOMP_SPINCOUNT", "30000")
