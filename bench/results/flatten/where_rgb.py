"""Where the outside rig's RGB error sits: moving masks vs static, static by image third."""
import sys, numpy as np, cv2, json
from pathlib import Path
data, run = Path(sys.argv[1]), Path(sys.argv[2])
tot = {}
for f in sorted((run / 'renders/rgb').glob('*.png')):
    gt = cv2.imread(str(data / 'rgb' / f.name))[..., ::-1].astype(np.float64) / 255
    pr = cv2.imread(str(f))[..., ::-1].astype(np.float64) / 255
    m = cv2.imread(str(data / 'masks/rgb' / f.name), cv2.IMREAD_UNCHANGED)
    mov = (m > 0) if m is not None else np.zeros(gt.shape[:2], bool)
    se = ((gt - pr) ** 2).mean(-1)
    h = se.shape[0]
    parts = {'moving': mov, 'static top': ~mov & (np.arange(h)[:, None] < h // 3),
             'static mid': ~mov & (np.arange(h)[:, None] >= h // 3) & (np.arange(h)[:, None] < 2 * h // 3),
             'static bottom': ~mov & (np.arange(h)[:, None] >= 2 * h // 3)}
    for k, msk in parts.items():
        a = tot.setdefault(k, [0.0, 0]); a[0] += se[msk].sum(); a[1] += msk.sum()
all_se = sum(v[0] for v in tot.values()); all_n = sum(v[1] for v in tot.values())
print(f"{run.parent.name}/{run.name}: whole PSNR {-10*np.log10(all_se/all_n):.2f} dB")
for k, (s, n) in tot.items():
    print(f"  {k:14s} {100*n/all_n:5.1f} % of pixels, {100*s/all_se:5.1f} % of squared error, PSNR {-10*np.log10(s/max(n,1)):.2f} dB")
