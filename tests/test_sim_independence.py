"""The simulator's renderer must not share code with the rasterizer it is used to grade."""
import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _imported_modules(package_dir: Path) -> set[str]:
    names = set()
    for path in package_dir.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path}: relative import (use absolute imports)"
                names.add(node.module)
    return names


def test_sim_sources_import_nothing_from_recon():
    names = _imported_modules(ROOT / "rig" / "sim")
    assert names, "scan found no imports at all: wrong directory?"
    assert not [n for n in names if n == "recon" or n.startswith("recon.")]


def test_splat_sources_import_nothing_from_the_simulator():
    names = _imported_modules(ROOT / "recon" / "splat")
    assert not [n for n in names if n.startswith("rig")]


def test_rendering_a_frame_loads_no_recon_module():
    code = (
        "import sys, json; from rig.sim import make_world\n"
        "w = make_world('default', 0); c, t = w.rig_pose(0, 1.0); k = w.rig_config.thermal.scaled(16, 12)\n"
        "w.render_temperature(t, k.fx, k.fy, k.cx, k.cy, 16, 12, 1.0); w.render_rgb(c, k.fx, k.fy, k.cx, k.cy, 16, 12, 1.0)\n"
        "print(json.dumps(sorted(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True)
    modules = json.loads(out.stdout)
    assert "rig.sim.raycast" in modules
    assert not [m for m in modules if m == "recon" or m.startswith("recon.")]
    assert "torch" not in modules
