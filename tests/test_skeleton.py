"""The package skeleton: importable, CLI answers, layering holds."""

import ast
from pathlib import Path

from monitor.cli import main

ROOT = Path(__file__).resolve().parent.parent


def test_cli_without_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "simulate" in capsys.readouterr().out


def test_cli_unknown_option_is_one_line_error(capsys):
    assert main(["simulate", "--no-such-option"]) == 2


def _imports(package: str) -> set[str]:
    found = set()
    for path in (ROOT / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module.split(".")[0])
    return found


def test_sim_imports_neither_drivers_nor_monitor():
    assert not _imports("sim") & {"drivers", "monitor", "serial", "pymodbus", "pyvista"}


def test_drivers_do_not_import_monitor():
    assert "monitor" not in _imports("drivers")
