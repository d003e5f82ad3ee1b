"""Per dataset: does paths.rest_px 1.0 change any moving path, and how many of the model's knots
would path_hold_rests hold. Where no moving path changes and no knot is held, the rests-only arm
is the same computation as dtg (dtg reads the still paths only with model.hold_in_place, off).

    python bench/results/rest-windows/acts.py DATA... > acts-SET.txt"""
import sys
from pathlib import Path
import torch
from recon.data import load_dataset
from recon.scene import Scene
from recon.train import paths as P
from recon.config import PathConfig
torch.set_grad_enabled(False)

def same(a, b):
    return len(a) == len(b) and all(p.knots.shape == q.knots.shape and torch.allclose(p.knots, q.knots, atol=1e-7)
                                    for p, q in zip(a, b))

for d in sys.argv[1:]:
    scene = Scene(load_dataset(Path(d)))
    plain, rest = P.tracked_paths(scene, PathConfig()), P.tracked_paths(scene, PathConfig(rest_px=1.0))
    knots = torch.linspace(0, 1, scene.steps_per_unit_time())     # a body's knots: one per time step
    held = [sum(int(((knots >= a - 1e-6) & (knots <= b + 1e-6)).sum()) for a, b in p.rests) for p in rest.moving]
    moving_same, still_same = same(plain.moving, rest.moving), same(plain.still, rest.still)
    acts = not (moving_same and sum(held) == 0)   # still paths: read only with hold_in_place (off in dtg)
    print(f"{Path(d).name}: moving {len(plain.moving)}->{len(rest.moving)} same={moving_same}, "
          f"still {len(plain.still)}->{len(rest.still)} same={still_same}, held knots {held} of {len(knots)} -> "
          f"{'ACTS' if acts else 'same computation'}", flush=True)
