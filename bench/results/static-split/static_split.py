"""Split a finished run's static-region thermal error (test views) into: halo of moving objects
(static pixels within R px of a moving mask in that frame), edges of static objects (within R px
of a static object's mask boundary), the rest. Static objects' interiors (not within R px of their edge) are `objects`.

    python bench/results/static-split/static_split.py RUN DATA 2 >> static_split.txt"""
import sys, json, numpy as np, cv2
from pathlib import Path
run, data = Path(sys.argv[1]), Path(sys.argv[2]); R = int(sys.argv[3]) if len(sys.argv) > 3 else 2
tf = json.loads((data / 'transforms.json').read_text())
labels = tf['mask_labels']; moving = [int(k) for k, v in labels.items() if v['moving']]
statics = [int(k) for k, v in labels.items() if not v['moving']]
scale = tf['thermal_scale_k']
acc = {'halo': [], 'edge': [], 'rest': [], 'objects': []}
k = np.ones((2 * R + 1, 2 * R + 1), np.uint8)
for f in tf['frames']:
    if f['modality'] != 'thermal' or f['camera'] != 'cam1':
        continue
    gt = cv2.imread(str(data / f['file_path']), cv2.IMREAD_UNCHANGED).astype(np.float64)
    pr = cv2.imread(str(run / 'renders' / f['file_path']), cv2.IMREAD_UNCHANGED).astype(np.float64)
    valid = gt > 0
    err = np.abs(gt - pr) * scale
    m = cv2.imread(str(data / f['mask_path']), cv2.IMREAD_UNCHANGED)
    mov = np.isin(m, moving)
    st = np.isin(m, statics)
    halo = cv2.dilate(mov.astype(np.uint8), k) > 0
    edge = (cv2.dilate(st.astype(np.uint8), k) > 0) & ~(cv2.erode(st.astype(np.uint8), k) > 0)
    static = valid & ~mov
    acc['halo'].append(err[static & halo]); acc['edge'].append(err[static & ~halo & edge])
    acc['objects'].append(err[static & ~halo & ~edge & st]); acc['rest'].append(err[static & ~halo & ~edge & ~st])
tot = sum(np.concatenate(v).sum() for v in acc.values()); n = sum(np.concatenate(v).size for v in acc.values())
print(f'{run}: static MAE {tot/n:.3f} K over {n} px')
for key, v in acc.items():
    v = np.concatenate(v)
    print(f'  {key:8s} {v.size:7d} px  MAE {v.mean():6.2f} K  share of static error {v.sum()/tot*100:5.1f} %  p95 {np.percentile(v,95):6.2f}')
