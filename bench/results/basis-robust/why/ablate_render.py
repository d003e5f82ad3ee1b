"""A trained dtg run's test-rig thermal renders with parts of the model switched off (F_th's geometry
gates closed; the bodies' Gaussians hidden): thermal MAE whole, on pixels whose truth never changes
by more than 2 K ("static"), and on those within 2 px of a strong edge of the truth ("static-edges").

    python bench/results/basis-robust/why/ablate_render.py RUN DATA
"""
import sys, json, numpy as np, cv2, torch
from pathlib import Path
ROOT = Path(__file__).resolve().parents[4]; sys.path.insert(0, str(ROOT))
from recon.render import load_run, render_frame
from recon.scene import Camera
from recon.data import viewmat_from_c2w_opengl
run, data = Path(sys.argv[1]), Path(sys.argv[2])
tf = json.loads((data / 'transforms.json').read_text()); scale = tf['thermal_scale_k']
frames = [f for f in tf['frames'] if f['modality'] == 'thermal' and f['camera'] == 'cam1']
gts = np.stack([cv2.imread(str(data / f['file_path']), cv2.IMREAD_UNCHANGED).astype(np.float64) * scale for f in frames])
moving = (gts.max(0) - gts.min(0)) > 2.0
def grade(model, facts, tag):
    k0, k1 = facts["thermal_range_k"]; e_all = []; e_st = []; e_ed = []
    for i, f in enumerate(frames):
        gt = gts[i]
        vm = torch.as_tensor(viewmat_from_c2w_opengl(np.asarray(f['transform_matrix'])), dtype=torch.float32)
        c = Camera(vm, f['fl_x'], f['fl_y'], f['cx'], f['cy'], f['w'], f['h'])
        with torch.no_grad():
            img = render_frame(model, "thermal", f['time'], c)[..., 0].numpy() * (k1 - k0) + k0
        e = np.abs(img - gt)
        g = np.hypot(cv2.Sobel(gt, cv2.CV_64F, 1, 0), cv2.Sobel(gt, cv2.CV_64F, 0, 1))
        edge = cv2.dilate((g > 8.0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool) & ~moving
        e_all.append(e.mean()); e_st.append(e[~moving].mean()); e_ed.append(e[edge].mean() if edge.any() else 0)
    print(f"{tag:28s} MAE {np.mean(e_all):.3f}  static {np.mean(e_st):.3f}  static-edges {np.mean(e_ed):.2f}")
model, facts = load_run(run)
grade(model, facts, "as trained")
g = model.gaussians
if "geometry_logit" in g:
    keep = g["geometry_logit"].clone()
    g["geometry_logit"].data.fill_(-30.0); grade(model, facts, "F_th geometry off")
    g["geometry_logit"].data.copy_(keep)
if "motion_basis" in g:
    mb = g["motion_basis"].clone(); bodies = mb > 0
    print("body members", int(bodies.sum()), "of", len(mb))
    op = g["opacity_thermal"].clone()
    g["opacity_thermal"].data[bodies] = -30.0; grade(model, facts, "bodies hidden (thermal)")
    g["opacity_thermal"].data.copy_(op)
