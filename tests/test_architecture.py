"""The arrows of DESIGN.md ("Layout") hold: read from every import statement of the core and
the built-in plugins (at module level, inside functions and under ``TYPE_CHECKING`` alike).

    cli (and web) -> fleet -> maintenance, measurement -> storage -> domain

and the plugin API (``catenary.plugins``) sits beside the domain: plugins import it and the
domain, never a command.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "platform" / "catenary"
PLUGINS = ROOT / "plugins"

SHARED = ("domain", "wiretype", "limits", "config", "errors", "arrays", "text")
"""Modules of ``catenary`` that every package shares."""

FORBIDDEN: dict[str, tuple[str, ...]] = {
    "catenary.measurement": ("catenary.maintenance", "catenary.cli", "catenary.fleet"),
    "catenary.maintenance": ("catenary.measurement", "catenary.cli", "catenary.fleet"),
    "catenary.storage": (
        "catenary.measurement",
        "catenary.maintenance",
        "catenary.cli",
        "catenary.fleet",
        "catenary.plugins",
    ),
    "catenary.plugins": ("catenary.measurement", "catenary.maintenance", "catenary.cli"),
    **{
        f"catenary.{name}": (
            "catenary.measurement",
            "catenary.maintenance",
            "catenary.storage",
            "catenary.cli",
            "catenary.fleet",
            "catenary.plugins",
        )
        for name in SHARED
    },
}
"""What the modules of a package (or a shared module) must never import."""


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, module: str) -> set[str]:
    """Every module ``path`` imports (``from x import y`` counts ``x`` and ``x.y``)."""
    found: set[str] = set()
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def _modules(root: Path) -> dict[str, set[str]]:
    return {
        _module_name(path, root): _imports(path, _module_name(path, root))
        for path in sorted(root.rglob("*.py"))
        if "__pycache__" not in path.parts
    }


def _under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def test_the_core_keeps_the_arrows() -> None:
    modules = _modules(CORE.parent)
    assert len(modules) > 40
    broken = [
        f"{module} imports {target}"
        for module, imports in modules.items()
        for package, forbidden in FORBIDDEN.items()
        if _under(module, package)
        for target in sorted(imports)
        if any(_under(target, f) for f in forbidden)
    ]
    assert not broken


def test_nothing_outside_the_cli_imports_it() -> None:
    modules = {**_modules(CORE.parent), **_modules(PLUGINS)}
    broken = [
        f"{module} imports {target}"
        for module, imports in modules.items()
        if not _under(module, "catenary.cli")
        for target in sorted(imports)
        if _under(target, "catenary.cli")
    ]
    assert not broken


def test_the_rules_see_a_violation(tmp_path: Path) -> None:
    """The checker itself: a measurement module importing maintenance is caught."""
    bad = tmp_path / "catenary" / "measurement" / "bad.py"
    bad.parent.mkdir(parents=True)
    (bad.parent / "__init__.py").write_text("")
    bad.write_text("def f():\n    from ..maintenance import alerts\n")
    imports = _modules(tmp_path)["catenary.measurement.bad"]
    assert "catenary.maintenance.alerts" in imports


@pytest.mark.parametrize("argv", [["--help"], ["process", "--help"], ["alerts", "--help"]])
def test_help_loads_no_numerical_module(argv: list[str]) -> None:
    """``catenary --help`` lists every command (the plugins' too) without importing the heavy
    modules: commands and plugins import them when they run."""
    heavy = ("scipy", "matplotlib", "pyarrow", "h5py")
    code = (
        "import sys\n"
        "from catenary.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print('loaded:', *(m for m in {heavy!r} if m in sys.modules))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert "Usage:" in result.stdout
    assert result.stdout.splitlines()[-1] == "loaded:"
