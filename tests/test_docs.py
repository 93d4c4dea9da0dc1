"""The documentation stays true to the code: docs/cli.md is what the parser gives, the README shows the test
command CI runs, and every relative link in README.md and docs/ (docs/notes/ included) points at a file that exists."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def gen_cli_docs():
    spec = importlib.util.spec_from_file_location("gen_cli_docs", ROOT / "tools" / "gen_cli_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def rendered(gen_cli_docs):
    return gen_cli_docs.render()


def test_cli_reference_is_current(rendered):
    current = (ROOT / "docs" / "cli.md").read_text()
    assert current == rendered, "docs/cli.md is out of date: run python tools/gen_cli_docs.py"


def test_cli_reference_lists_every_command_and_option(rendered):
    from photorecon.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, sp in sub.choices.items():
        assert f"## photorecon {name}\n" in rendered
        section = rendered.split(f"## photorecon {name}\n", 1)[1].split("\n## photorecon ", 1)[0]
        for action in sp._actions:
            for opt in action.option_strings:
                if opt not in ("-h", "--help", "-q", "--quiet", "-v", "--verbose"):
                    found = re.search(rf"(?<![\w.-]){re.escape(opt)}(?![\w.-])", section)
                    assert found, f"photorecon {name}: {opt} missing from docs/cli.md"


def test_check_mode_fails_on_a_stale_file(gen_cli_docs, rendered, tmp_path, capsys):
    stale = tmp_path / "cli.md"
    stale.write_text(rendered.replace("## photorecon fuse", "## photorecon fuze"))
    assert gen_cli_docs.main(["--check", "-o", str(stale)]) == 1
    fresh = tmp_path / "fresh.md"
    assert gen_cli_docs.main(["-o", str(fresh)]) == 0
    assert gen_cli_docs.main(["--check", "-o", str(fresh)]) == 0
    capsys.readouterr()


def test_readme_shows_the_test_command_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    command = next(line.strip() for line in ci.splitlines() if "pytest" in line and not line.lstrip().startswith("#"))
    assert command in (ROOT / "README.md").read_text()


def _markdown_files():
    return [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]


@pytest.mark.parametrize("page", _markdown_files(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page):
    text = page.read_text()
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+://|mailto:|#", target):
            continue
        path = (page.parent / target.split("#", 1)[0]).resolve()
        if not path.exists():
            broken.append(target)
    assert not broken, f"{page.name}: links to missing files: {broken}"
