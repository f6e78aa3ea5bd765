"""The README's layout section is a true map of the tree, and the package root stays trimmed."""

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
