"""The fields package imports in one direction: no cycles, no imports hidden in functions, no splats."""

import ast
import subprocess
import sys
from pathlib import Path

import pointfield

SOURCE = Path(pointfield.__file__).parent
OWNED_ELSEWHERE = {"pointfield.fields.train", "pointfield.fields.views", "pointfield.fields.exercise"}
"""The training and rendering commands: they sit on top of the package, and may import lazily."""


def _module_file(name: str) -> Path | None:
    path = SOURCE.parent.joinpath(*name.split("."))
    for candidate in (path.with_suffix(".py"), path / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imports(name: str, top_level_only: bool) -> set[str]:
    """The pointfield modules that module ``name`` names in its import statements."""
    tree = ast.parse(_module_file(name).read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {module for module in found if module.startswith("pointfield") and _module_file(module)}


def _fields_modules() -> list[str]:
    modules = []
    for path in sorted((SOURCE / "fields").rglob("*.py")):
        parts = path.relative_to(SOURCE.parent).with_suffix("").parts
        modules.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return [module for module in modules if module not in OWNED_ELSEWHERE]


def test_the_modules_ngp_imports_never_import_it_back():
    graph, pending = {}, ["pointfield.fields.ngp"]
    while pending:
        module = pending.pop()
        if module not in graph:
            graph[module] = _imports(module, top_level_only=True)
            pending.extend(graph[module])
    # Depth-first search for a cycle through the explicit imports.
    state: dict[str, str] = {}

    def visit(module, path):
        state[module] = "open"
        for target in graph[module]:
            assert state.get(target) != "open", f"import cycle: {' -> '.join(path + [module, target])}"
            if target not in state:
                visit(target, path + [module])
        state[module] = "done"

    visit("pointfield.fields.ngp", [])
    assert not any(module.startswith("pointfield.splats") for module in graph), sorted(graph)


def test_fields_modules_import_pointfield_at_the_top_only():
    for module in _fields_modules():
        hidden = _imports(module, top_level_only=False) - _imports(module, top_level_only=True)
        assert not hidden, f"{module} imports {sorted(hidden)} inside a function"


def test_importing_the_fast_field_loads_neither_the_splats_nor_the_training_code():
    code = ("import sys, pointfield.fields.ngp; "
            "print(sorted(m for m in sys.modules if m.startswith(('pointfield.splats', 'pointfield.fields.train'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "[]"
