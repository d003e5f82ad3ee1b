"""The layout keeps the data's direction: no module imports form a cycle, and the
capture side never imports the reconstruction side."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "recon", "server")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, known: set[str]) -> set[str]:
    """Project modules a file imports, at module level or inside functions (a deferred import
    only hides a cycle)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        out |= {n for n in names if n in known}
    return out


def graph() -> dict[str, set[str]]:
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    known = {module_name(p) for p in files}
    return {module_name(p): imports(p, known) - {module_name(p)} for p in files}


def find_cycle(g: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}

    def visit(n, stack):
        state[n] = 1
        for d in sorted(g.get(n, ())):
            if d.rsplit(".", 1)[0] == n and d not in g:   # `from pkg import name` of a non-module
                continue
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state and (c := visit(d, stack + [d])):
                return c
        state[n] = 2
        return None

    for n in sorted(g):
        if n not in state and (c := visit(n, [n])):
            return c
    return None


def test_no_import_cycles():
    g = graph()
    # a package's __init__ re-exporting its modules is not a cycle of the modules themselves
    g = {n: {d for d in deps if not (n.startswith(d + ".") and d in g)} for n, deps in g.items()}
    assert find_cycle(g) is None, " -> ".join(find_cycle(g))


def test_rig_never_imports_recon():
    g = graph()
    offenders = {n: sorted(d for d in deps if d.startswith("recon")) for n, deps in g.items() if n.startswith("rig")}
    assert not {n: d for n, d in offenders.items() if d}


def test_the_model_the_loop_and_live_operation_are_layers():
    """recon/dtg (the model) never imports how it is trained (recon/train) or run live
    (recon/live); the training loop never imports live operation; none of them imports the status
    server, which only reads what recon publishes (the CLI layer, recon/run.py, starts it)."""
    g = graph()
    below = {"recon.dtg": ("recon.train", "recon.live", "recon.run", "server"),
             "recon.train": ("recon.live", "recon.run", "server"),
             "recon.live": ("recon.run", "server")}
    wrong = {n: sorted(d for d in deps if d.startswith(forbidden))
             for layer, forbidden in below.items() for n, deps in g.items() if n.startswith(layer + ".")}
    assert not {n: d for n, d in wrong.items() if d}, wrong
