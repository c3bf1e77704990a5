"""The package's floors: every import goes down (or stays in its own package), and the numpy floors load
without PyBullet."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "ftcgym"
#: floor of each part of ftcgym; a module may import from its own part or from a lower floor only
FLOORS = {"registry": 0, "criteria": 0, "settings": 0, "models": 0,
          "envs": 1, "fdd": 1, "vector": 1,
          "agents": 2,
          "task_envs": 3,
          "benchmark": 4,
          "training": 5,
          "cli": 6}


def part_of(module: str) -> str:
    """'ftcgym.fdd.aekf' -> 'fdd'; the package's own __init__ -> ''."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def module_name(path: Path) -> str:
    relative = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = relative.parts[:-1] if relative.name == "__init__" else relative.parts
    return ".".join(parts)


def imported_modules(path: Path) -> set[str]:
    """Every ftcgym module `path` imports, at the top or inside a function, relative imports resolved."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return {module for module in found if module.split(".")[0] == "ftcgym"}


def upward_imports() -> list[str]:
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = module_name(path)
        here = part_of(source)
        for target in sorted(imported_modules(path)):
            there = part_of(target)
            if there not in FLOORS or here == there or here == "":
                continue
            if here not in FLOORS:
                bad.append(f"{source}: part {here!r} has no floor in the layout test")
            elif FLOORS[there] >= FLOORS[here]:
                bad.append(f"{source} imports {target} (floor {FLOORS[here]} -> {FLOORS[there]})")
    return bad


def test_every_part_has_a_floor():
    parts = {path.stem if path.is_file() else path.name for path in PACKAGE.iterdir()
             if (path.suffix == ".py" and path.stem != "__init__") or (path / "__init__.py").exists()}
    assert parts == set(FLOORS)


def test_every_import_goes_down():
    assert upward_imports() == []


def test_the_walk_sees_an_upward_import(tmp_path, monkeypatch):
    """The check can fail: an fdd module importing envs is reported."""
    fake = tmp_path / "ftcgym"
    (fake / "fdd").mkdir(parents=True)
    (fake / "fdd" / "bad.py").write_text("from ..envs.world import PyBulletWorld\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    assert upward_imports() == ["ftcgym.fdd.bad imports ftcgym.envs.world (floor 1 -> 1)",
                                "ftcgym.fdd.bad imports ftcgym.envs.world.PyBulletWorld (floor 1 -> 1)"]


@pytest.mark.parametrize("module", ["ftcgym.models", "ftcgym.fdd", "ftcgym.agents", "ftcgym.fdd.replay",
                                    "ftcgym.fdd.airdata_ekf", "ftcgym.fdd.iv_change", "ftcgym.fdd.aekf",
                                    "ftcgym.fdd.propulsion_bayes"])
def test_numpy_floors_load_without_pybullet(module):
    code = f"import sys, {module}; print('pybullet' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
