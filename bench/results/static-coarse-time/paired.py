"""Per seed, two methods' finished runs side by side (A/B for each metric), medians, and on how many
seeds B's thermal MAE is lower:

    python bench/results/static-coarse-time/paired.py ROOT_A METHOD_A METHOD_B [ROOT_B]
"""
import json, sys, statistics as st
from pathlib import Path
root = Path(sys.argv[1]); a, b = sys.argv[2], sys.argv[3]
rootb = Path(sys.argv[4]) if len(sys.argv) > 4 else root
keys = ['rgb', 'th', 'mae', 'mov', 'movhot', 'static', 'it', 'worstobj']
def m(p):
    d = json.loads(p.read_text()); x = d['metrics']; r = x['regions']['thermal']
    objs = [o['mae_k'] for o in x.get('objects', {}).get('thermal', {}).values() if o.get('moving')] if isinstance(x.get('objects'), dict) else []
    v = [x['rgb']['psnr'], x['thermal']['psnr'], x['thermal']['mae_k'], r['moving']['mae_k'], r['moving_hot']['mae_k'], r['static']['mae_k'], d['iterations'], max(objs) if objs else float('nan')]
    return [float('nan') if u is None else u for u in v]
for sc in ('family-inside', 'family-outside'):
    ra, rb = [], []
    for d in sorted(root.glob(f'runs/{sc}-s*')):
        pa, pb = d / a / 'metrics.json', rootb / 'runs' / d.name / b / 'metrics.json'
        if not (pa.exists() and pb.exists()): continue
        x, y = m(pa), m(pb); ra.append(x); rb.append(y)
        print(d.name, ' '.join(f'{k} {u:.2f}/{v:.2f}' for k, u, v in zip(keys, x, y)))
    if ra:
        print('MEDIAN', sc, ' '.join(f'{k} {st.median(c):.2f}/{st.median(e):.2f}' for k, c, e in zip(keys, zip(*ra), zip(*rb))))
        print('better mae on', sum(y[2] < x[2] for x, y in zip(ra, rb)), 'of', len(ra))
