"""The docs as readers meet them: README is a front door (short, the quick start near the top, a link to
every page), the API reference covers the whole public API, and the CLI page every command. ``make lint`` builds the
site itself in strict mode (``mkdocs build --strict``: broken links and anchors, bad docstrings)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"


def _assigned(path: Path, name: str):
    """The literal value of the module-level assignment ``name = ...`` in ``path`` (read, not imported)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        if any(getattr(t, "id", None) == name for t in targets):
            return node.value
    raise AssertionError(f"{path} assigns no {name}")


def test_the_readme_is_a_front_door_with_the_quick_start_in_its_first_60_lines():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines: move the detail to a page under docs/"
    first_code = next(i for i, line in enumerate(lines, 1) if line.startswith("from hub_envs import"))
    assert first_code <= 60, f"the Python quick start starts at line {first_code} of README.md"


def test_the_readme_links_every_docs_page():
    readme = README.read_text(encoding="utf-8")
    unlinked = [p.name for p in sorted(DOCS.glob("*.md")) if f"](docs/{p.name}" not in readme]
    assert not unlinked, f"README.md's Documentation list does not link {unlinked}"


def test_the_api_reference_documents_every_public_name():
    exports = ast.literal_eval(_assigned(ROOT / "hub_envs" / "__init__.py", "_EXPORTS"))  # the names of __all__
    page = (DOCS / "api.md").read_text(encoding="utf-8")
    missing = [f"{module}.{name}" for name, module in exports.items() if f"::: {module}.{name}\n" not in page]
    assert not missing, f"docs/api.md has no `::: path` entry for {missing}"
    assert "::: hub_envs.errors\n" in page and "__version__" in page


def test_the_cli_page_names_every_command():
    table = _assigned(ROOT / "hub_envs" / "cli" / "__init__.py", "COMMANDS")
    commands = [ast.literal_eval(key) for key in table.keys]
    page = (DOCS / "cli.md").read_text(encoding="utf-8")
    missing = [c for c in commands if f"`hub-envs {c}" not in page]
    assert not missing, f"docs/cli.md does not name {missing}"


def test_the_docs_site_lists_every_page_in_its_nav():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    missing = [p.name for p in sorted(DOCS.glob("*.md")) if f": {p.name}\n" not in config]
    assert not missing, f"mkdocs.yml's nav lacks {missing}"
