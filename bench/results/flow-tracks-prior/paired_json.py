"""Per seed, two methods side by side from bench/table.py's table.json files (A/B for each metric),
medians, and on how many seeds B is better:

    python bench/results/flow-tracks-prior/paired_json.py TABLE_A.json METHOD_A TABLE_B.json METHOD_B
"""
import json, sys, statistics as st
a_path, a, b_path, b = sys.argv[1:5]
keys = [('psnr_rgb', 'rgb', 1), ('psnr_thermal', 'th', 1), ('mae_k_thermal', 'mae', -1), ('mae_k_moving', 'mov', -1),
        ('mae_k_moving_hot', 'movhot', -1), ('mae_k_static', 'static', -1), ('iterations', 'it', 0)]
def runs(path, method):
    return {(r['scene'], r['seed']): r for r in json.load(open(path))['per_run'] if r['method'] == method}
ra, rb = runs(a_path, a), runs(b_path, b)
for scene in sorted({s for s, _ in ra}):
    pairs = [(ra[k], rb[k]) for k in sorted(ra) if k[0] == scene and k in rb]
    for x, y in pairs:
        print(f"{scene}-s{x['seed']}", ' '.join(f"{n} {x[k] or float('nan'):.2f}/{y[k] or float('nan'):.2f}" for k, n, _ in keys))
    if pairs:
        print('MEDIAN', scene, ' '.join(f"{n} {st.median(x[k] or float('nan') for x, _ in pairs):.2f}/"
                                        f"{st.median(y[k] or float('nan') for _, y in pairs):.2f}" for k, n, _ in keys))
        print('  B better: thermal MAE on', sum(y['mae_k_thermal'] < x['mae_k_thermal'] for x, y in pairs),
              'RGB on', sum((y['psnr_rgb'] or 0) > (x['psnr_rgb'] or 0) for x, y in pairs), 'of', len(pairs))
