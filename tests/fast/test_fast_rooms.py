"""puppet.fast knows nothing of servos, readings, rigs or the loop: arrays and patterns in,
transforms out (DESIGN.md, parts and their rooms)."""

import ast
from pathlib import Path

import puppet.fast

# puppet._kinematics: native array kernels (PoseFill gathers constraint values through it), no servos or rigs.
ALLOWED = ("puppet.fast", "puppet._native", "puppet._kinematics", "puppet.errors", "puppet.cache")


def imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.update(f"{node.module}.{alias.name}" if node.module == "puppet" else node.module
                         for alias in node.names)
    return names


def test_fast_imports_only_its_own_room():
    folder = Path(puppet.fast.__file__).parent
    outside = {f"{path.name}: {name}" for path in folder.glob("*.py") for name in imported_modules(path)
               if name.startswith("puppet") and not name.startswith(ALLOWED)}
    assert outside == set()
