"""The package's architecture: dependencies point one way, no import cycles, no hardware on import."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import plantsim

PACKAGE = Path(plantsim.__file__).resolve().parent

# Layers, lowest first: a module may import (at load time) only from its own layer or below.
LAYERS = [
    {"plantsim._lazy", "plantsim._cores", "plantsim.errors", "plantsim.transforms", "plantsim.resources", "plantsim.timestamps",
     "plantsim.validation", "plantsim.interrupts"},
    {"plantsim.plant"},
    {"plantsim.rig"},
    {"plantsim.sensor", "plantsim.turntable"},
    {"plantsim.scan.schedule", "plantsim.scan.raw", "plantsim.scan.journal", "plantsim.scan.config",
     "plantsim.scan.plan"},
    {"plantsim.cloud"},
    {"plantsim.scan.pipeline", "plantsim.scan.session", "plantsim.scan"},
    {"plantsim.evaluation", "plantsim.hardware"},
    {"plantsim.cli", "plantsim", "plantsim.__main__"},
]
SUBPACKAGES = ["plant", "rig", "sensor", "turntable", "scan", "cloud", "evaluation", "hardware", "cli"]


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> int:
    best, rank = -1, None
    for i, layer in enumerate(LAYERS):
        for prefix in layer:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best:
                best, rank = len(prefix), i
    assert rank is not None, f"{module} is in no layer: add it to LAYERS"
    return rank


def load_time_imports(path: Path) -> set[str]:
    """plantsim modules imported when ``path`` is loaded (not inside functions or TYPE_CHECKING)."""
    tree = ast.parse(path.read_text())
    found = set()

    def visit(body):
        for node in body:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                continue
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("plantsim"):
                for alias in node.names:
                    candidate = f"{node.module}.{alias.name}"
                    found.add(candidate if (PACKAGE.parent / candidate.replace(".", "/")).with_suffix(".py").exists()
                              or (PACKAGE.parent / candidate.replace(".", "/")).is_dir() else node.module)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("plantsim"))
            elif isinstance(node, (ast.If, ast.Try)):
                visit(node.body)
                for handler in getattr(node, "handlers", []):
                    visit(handler.body)
                visit(node.orelse)

    visit(tree.body)
    return found


GRAPH = {module_name(p): load_time_imports(p) for p in PACKAGE.rglob("*.py")}


def test_every_module_sits_in_a_layer_and_imports_only_downwards():
    upward = []
    for module, imports in GRAPH.items():
        for target in imports:
            if layer_of(target) > layer_of(module):
                upward.append(f"{module} -> {target}")
    assert not upward, "imports that climb the layers: " + ", ".join(sorted(upward))


def test_no_import_cycles():
    def package_of(name):
        return name if name in GRAPH else name.rsplit(".", 1)[0]

    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for target in GRAPH.get(node, ()):
            target = package_of(target)
            if target == node or target not in GRAPH:
                continue
            if state.get(target) == 1 and not node.startswith(target + "."):  # a package importing its child is fine
                cycle = stack[stack.index(target):] + [target]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target)
        stack.pop()
        state[node] = 2

    for module in GRAPH:
        if module not in state:
            visit(module)


@pytest.mark.parametrize("subpackage", SUBPACKAGES)
def test_each_subpackage_imports_on_its_own(subpackage):
    result = subprocess.run([sys.executable, "-c", f"import plantsim.{subpackage}"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_import_plantsim_loads_no_hardware_and_no_optional_dependencies():
    code = ("import sys, plantsim; bad = sorted(m for m in sys.modules if m.startswith(('plantsim.hardware', "
            "'serial', 'dynamixel_sdk', 'rosbags', 'matplotlib', 'plantsim.evaluation', 'plantsim.cli'))); "
            "print(','.join(bad))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ""


def test_the_public_api_is_listed_once_and_resolves():
    assert len(plantsim.__all__) == len(set(plantsim.__all__))
    for name in plantsim.__all__:
        assert getattr(plantsim, name) is not None, name
    assert "run_scan" in dir(plantsim) and "TurntableOptions" in plantsim.__all__
