"""A/B of dtg's per-step cost with and without F_th geometry (bench/train_step.py, method added here)."""
import runpy, sys
sys.path.insert(0, "/work/main")
import recon.config as c
c.METHODS["dtg-nogeo"] = c._with(c.METHODS["dtg"], {"model": {"deform_geometry": ()}})
sys.argv = ["train_step.py"] + sys.argv[1:]
runpy.run_path("/work/main/bench/train_step.py", run_name="__main__")
