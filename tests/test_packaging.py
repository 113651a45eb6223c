"""pyproject.toml declares every third-party package that evservo imports at module level (a lazy
import inside a function belongs to an optional driver and is not required)."""

import ast
import re
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _top_level_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.parse(path.read_text()).body:  # module level only
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_top_level_import_is_a_declared_dependency():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {_canonical(re.split(r"[<>=!~ \[;]", d, maxsplit=1)[0]) for d in project["dependencies"]}
    imported = set().union(*(_top_level_imports(p) for p in (ROOT / "python/evservo").rglob("*.py")))
    third_party = imported - set(sys.stdlib_module_names) - {"evservo", "__future__"}
    dists = packages_distributions()
    missing = {m: dists.get(m) for m in third_party if not {_canonical(d) for d in dists.get(m, [])} & declared}
    assert not missing, f"imported at module level but not in pyproject.toml dependencies: {missing}"
    # The ones issue 10 found missing are there now.
    assert {"mujoco", "qpsolvers", "daqp", "hdf5plugin", "pillow"} <= declared
