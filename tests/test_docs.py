"""The README's commands exist and every relative link in README.md and docs/ resolves."""
import re
from pathlib import Path

import pytest

from recon.cli import main as recon_main
from rig.cli import main as rig_main

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def readme_commands() -> list[tuple[str, str]]:
    """(program, subcommand) of every `rig X` / `recon X` line in the README's code blocks."""
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    found = re.findall(r"^(rig|recon) ([a-z-]+)", "\n".join(blocks), re.M)
    return sorted(set(found))


def test_the_readme_shows_commands():
    assert {("recon", "run"), ("rig", "capture"), ("recon", "prepare")} <= set(readme_commands())


@pytest.mark.parametrize("program,command", readme_commands())
def test_every_readme_command_exists(program, command, capsys):
    main = recon_main if program == "recon" else rig_main
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0 and "usage:" in capsys.readouterr().out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    links = re.findall(r"\]\(([^)\s]+)\)", page.read_text())
    broken = [link for link in links if not re.match(r"https?://|#|mailto:", link)
              and not (page.parent / link.split("#")[0]).exists()]
    assert not broken, f"{page.name}: {broken}"


def test_readme_is_a_first_screen():
    assert len((ROOT / "README.md").read_text().splitlines()) < 200
