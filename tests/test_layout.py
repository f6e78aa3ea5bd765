"""The README's layout section is a true map of the tree, and the package root stays trimmed."""

import ast
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "pointfield"
ROOT_MODULES = {
    "__init__", "__main__", "atomic", "classify", "compiling", "devices", "errors", "metrics", "runs", "segment",
    "version",
}


def layout_block() -> str:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("## Layout"):]
    return section[section.index("```"): section.index("```", section.index("```") + 3)]


def test_the_readme_layout_names_every_package_and_subpackage():
    block = layout_block()
    packages = [p for p in PACKAGE.rglob("__init__.py") if p.parent != PACKAGE and len(p.relative_to(PACKAGE).parts) <= 3]
    for init in packages:
        name = init.parent.name + "/"
        assert name in block, f"README layout does not mention {init.parent.relative_to(PACKAGE)}/"


def test_the_readme_layout_names_only_folders_that_exist():
    block = layout_block()
    named = set(re.findall(r"([a-z_]+)/", block)) - {"src", "pointfield", "tests", "benchmarks", "docs", "shared", "data"}
    existing = {p.name for p in PACKAGE.rglob("*") if p.is_dir() and p.name != "__pycache__"}
    assert named <= existing, f"README layout names folders that do not exist: {sorted(named - existing)}"


def test_the_package_root_holds_only_the_trimmed_set_of_modules():
    modules = {p.stem for p in PACKAGE.glob("*.py")}
    assert modules == ROOT_MODULES, f"unexpected modules at the package root: {sorted(modules ^ ROOT_MODULES)}"
    block = layout_block()
    for name in ROOT_MODULES - {"__main__"}:
        assert f"{name}.py" in block, f"README layout does not mention {name}.py"


def test_importing_the_hash_grid_field_imports_nothing_that_imports_it_back(checkout_environment):
    # The check anyone can run: python -c "import pointfield.fields.ngp" pulls in neither the
    # training code nor the splats, the two places that used to import back into the fields.
    code = (
        "import sys, pointfield.fields.ngp; "
        "print(sorted(m for m in sys.modules if m.startswith(('pointfield.splats', 'pointfield.fields.train',"
        " 'pointfield.training', 'pointfield.fields.run'))))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                            env=checkout_environment)
    assert result.stdout.strip() == "[]"


def _imported_private_names(module: Path) -> list[tuple[int, str]]:
    """``(line, "package.module._name")`` for each private name ``module`` imports from another package.

    A package is a folder of modules: a module may use its own package's private helpers (the PLY
    reader's, from the PLY chunk reader), never another's, so that a package's internals can change
    without breaking its neighbours.
    """
    own = ".".join(module.relative_to(PACKAGE.parent).with_suffix("").parts[:-1])
    found = []
    for node in ast.walk(ast.parse(module.read_text(encoding="utf-8"), str(module))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("pointfield"):
            source = importlib.util.find_spec(node.module)
            package = node.module if source.submodule_search_locations else node.module.rpartition(".")[0]
            names = [(node.module.split("."), alias.name) for alias in node.names]
        elif isinstance(node, ast.Import):
            names = [(alias.name.split(".")[:-1], alias.name.split(".")[-1]) for alias in node.names
                     if alias.name.startswith("pointfield")]
            package = None
        else:
            continue
        for parts, name in names:
            private = [p for p in [*parts, name] if p.startswith("_") and not p.startswith("__")]
            if private and (package or ".".join(parts)) != own:
                found.append((node.lineno, ".".join([*parts, name])))
    return found


def test_no_module_imports_a_private_name_of_another_package():
    # The streaming verbs once imported some 25 helpers private to the LAS, PCD and PLY packages; a format's
    # chunk reader and writer are now public, registered beside its whole-file reader and writer.
    offenders = [f"{module.relative_to(ROOT)}:{line}: {name}" for module in sorted(PACKAGE.rglob("*.py"))
                 for line, name in _imported_private_names(module)]
    assert offenders == [], "private names imported across packages:\n" + "\n".join(offenders)
