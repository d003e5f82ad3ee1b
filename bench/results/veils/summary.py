"""Medians over the runs of bench/veils.py's JSON, per case (the run folder's scene) and kind of object.

    python bench/results/veils/summary.py bench/results/veils/dev.json [OTHER.json]"""
import json
import sys

import numpy as np

for path in sys.argv[1:]:
    rows = json.load(open(path))
    groups = {}
    for row in rows:
        case = 'outside' if 'outside' in row['run'] else 'inside'
        for name, o in row['objects'].items():
            kind = 'moving' if o['moves'] else name
            groups.setdefault((case, kind), []).append(o)
    print(path)
    for (case, kind), objs in sorted(groups.items()):
        med = lambda k: float(np.median([o[k] for o in objs]))  # noqa: E731
        print(f'  {case:7s} {kind:7s} n={len(objs):2d}  MAE median {med("mae_k"):5.1f} K (worst {max(o["mae_k"] for o in objs):5.1f}), '
              f'drawn by itself alone {med("mae_k_on_object_alone"):5.1f} K; blend weight off the object {med("share_off"):.2f} '
              f'(worst {max(o["share_off"] for o in objs):.2f})')
