"""Sphinx configuration of pointfield's API reference: ``make docs`` builds it into docs/_build/api.

Every module of the package gets a page (autosummary, recursively), each public name documented
in the module that defines it; a name a package re-exports (``pointfield.read``) links to that
page rather than being documented twice. Docstrings are read as Google / NumPy style
(napoleon) and reStructuredText. No intersphinx: the build needs no network.
"""

import importlib
import inspect
import pkgutil
import sys
from pathlib import Path

from sphinx.errors import ExtensionError

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))

import pointfield  # noqa: E402 (after src/ is on the path)

project = "pointfield"
release = pointfield.__version__
extensions = ["sphinx.ext.autodoc", "sphinx.ext.autosummary", "sphinx.ext.napoleon"]
autosummary_generate = True
# Each name on the page of the module that defines it: a package's __all__ re-exports are not
# documented again (they would be duplicate descriptions).
autodoc_default_options = {
    "members": True,
    "undoc-members": True,
    "show-inheritance": True,
    "ignore-module-all": True,
}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
exclude_patterns = ["_build"]
html_theme = "alabaster"
html_title = f"pointfield {release} API reference"



def public_names() -> dict[str, list[str]]:
    """Module -> the public classes and functions it defines, for every module of the package."""
    found = {}
    for module_info in pkgutil.walk_packages(pointfield.__path__, "pointfield."):
        if module_info.name.rpartition(".")[2].startswith("_"):
            continue
        module = importlib.import_module(module_info.name)
        found[module.__name__] = [
            name for name, value in vars(module).items()
            if not name.startswith("_") and (inspect.isclass(value) or inspect.isfunction(value))
            and value.__module__ == module.__name__
        ]
    return found


def check_every_public_name(app, env) -> None:
    """Fail the build when a public class or function of a module, or a name of ``pointfield.__all__``,
    has no entry in the reference (a module left out, an import error that hid its members)."""
    documented = set(env.get_domain("py").objects)
    missing = [f"{module}.{name}" for module, names in public_names().items() for name in names
               if f"{module}.{name}" not in documented]
    missing += [f"{module}" for module in public_names() if module not in documented]
    for name in pointfield.__all__:
        value = getattr(pointfield, name)
        if inspect.isclass(value) or inspect.isfunction(value):
            if f"{value.__module__}.{value.__qualname__}" not in documented:
                missing.append(f"pointfield.{name} ({value.__module__}.{value.__qualname__})")
    if missing:
        raise ExtensionError(f"{len(missing)} public names are not in the API reference: {', '.join(missing[:20])}")


def setup(app):
    app.connect("env-check-consistency", check_every_public_name)
