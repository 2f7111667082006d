"""The package's shape: imports only go down the layers, no private name crosses a module, and the public face is
literal, complete and cheap to import. (The module table and the documentation's snippets: tests/test_docs.py.)"""

import ast
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "seaice_jax"

LAYERS = {"geometry": 1, "sensors": 2, "adjust": 3, "imagery": 4, "drift": 4, "io": 5, "simulate": 5,
          "workflows": 6, "report": 6, "cli": 7}
"""Layer of each subpackage (or top-level module); modules at the package base not named here are layer 0."""


def _modules():
    """``{dotted name: path}`` of every module of the package."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS.get(parts[1], 0) if len(parts) > 1 else 0


def _imports(path: Path, module: str):
    """``(line, imported module, imported names)`` of every import statement (also inside functions)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[:len(package.split(".")) - node.level + 1] + ([base] if base
                                                                                                   else []))
            yield node.lineno, base, tuple(alias.name for alias in node.names)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_layer_rule_is_checkable():
    """The walker sees the package's own imports (a broken walker would make the next tests vacuous)."""
    seen = {target for module, path in _modules().items() for _, target, _ in _imports(path, module)}
    assert "seaice_jax.geometry.earth" in seen and "seaice_jax.errors" in seen
    assert _layer("seaice_jax.workflows.radar_block") > _layer("seaice_jax.io.project") > _layer(
        "seaice_jax.drift.kinematics") > _layer("seaice_jax.adjust.engine.lsq") > _layer(
        "seaice_jax.sensors.slar") > _layer("seaice_jax.geometry.scan") > _layer("seaice_jax.errors")


def test_no_import_goes_up_a_layer():
    problems = []
    for module, path in _modules().items():
        if module == "seaice_jax":  # the public face re-exports from every layer
            continue
        for line, target, _ in _imports(path, module):
            if target.startswith("seaice_jax.") and _layer(target) > _layer(module):
                problems.append(f"{path.relative_to(ROOT)}:{line}: {module} (layer {_layer(module)}) imports "
                                f"{target} (layer {_layer(target)})")
    assert not problems, "\n".join(problems)


ADJUST_MODELS = ("orbit", "radar", "sequence")
"""The model packages of ``seaice_jax.adjust``, each declaring its problems on the engine."""


def test_engine_imports_only_the_package_base():
    """``adjust.engine`` knows no model, sensor, geometry or file format: besides its own modules it imports only
    layer-0 modules of the package (errors, array shapes, small linear algebra); a model package imports the engine
    and no other model package."""
    problems = []
    for module, path in _modules().items():
        if not module.startswith("seaice_jax.adjust."):
            continue
        part = module.split(".")[2]
        for line, source, names in _imports(path, module):
            # ``from seaice_jax.adjust import engine`` imports the module seaice_jax.adjust.engine
            for target in [f"{source}.{n}" for n in names] if source == "seaice_jax.adjust" else [source]:
                if part == "engine":
                    allowed = not target.startswith("seaice_jax.") or target.startswith(
                        "seaice_jax.adjust.engine") or _layer(target) == 0
                else:
                    allowed = not target.startswith("seaice_jax.adjust") or target.split(".")[2] in (part, "engine")
                if not allowed:
                    problems.append(f"{path.relative_to(ROOT)}:{line}: {module} imports {target}")
    assert not problems, "\n".join(problems)
    assert {m.split(".")[2] for m in _modules() if m.startswith("seaice_jax.adjust.")} == {"engine", *ADJUST_MODELS}


def test_no_private_name_crosses_a_module():
    """No ``from module import _name`` between modules (a private *module* of the package, such as ``_config``, may
    be imported)."""
    modules = _modules()
    problems = []
    for module, path in modules.items():
        for line, target, names in _imports(path, module):
            if target.startswith("seaice_jax") and target != module:
                problems += [f"{path.relative_to(ROOT)}:{line}: imports {name} from {target}" for name in names
                             if _is_private(name) and f"{target}.{name}" not in modules]
    assert not problems, "\n".join(problems)


def _own_members(tree) -> set[str]:
    """Names a module defines on its classes and instances: methods, class fields, ``self.x = ...`` targets."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef):
                    names.add(item.name)
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    names.add(item.target.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
    return names


NAMED_TUPLE_API = {"_replace", "_asdict", "_fields", "_make"}
"""A ``typing.NamedTuple``'s public methods (underscored so as not to clash with its fields)."""


def test_no_private_attribute_of_another_module():
    """``thing._name`` only where this module defines ``_name`` (e.g. not ``model._forward`` of a scan model from
    a simulator)."""
    problems = []
    for path in _modules().values():
        tree = ast.parse(path.read_text())
        own = _own_members(tree) | NAMED_TUPLE_API
        problems += [f"{path.relative_to(ROOT)}:{node.lineno}: .{node.attr}" for node in ast.walk(tree)
                     if isinstance(node, ast.Attribute) and _is_private(node.attr) and node.attr not in own]
    assert not problems, "\n".join(problems)


def test_public_face_is_written_once_complete_and_cheap():
    """The public names are written once, as the type checker's imports in ``seaice_jax/__init__.py`` (plus the
    errors): ``__all__`` and the lazy table are exactly those, in that order (errors last), with the user API in
    it; every name resolves; importing the package loads neither OpenCV, matplotlib nor xarray."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    checked = next(node for node in tree.body if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING")
    typed = [alias.name for node in checked.body if isinstance(node, ast.ImportFrom) for alias in node.names]
    errors = [alias.name for node in tree.body
              if isinstance(node, ast.ImportFrom) and node.module == "seaice_jax.errors" for alias in node.names]
    import seaice_jax
    names = list(seaice_jax.__all__)
    assert names == typed + errors and len(names) == len(set(names))
    assert list(seaice_jax._LAZY) == names
    assert {"fit_scan_model", "remap", "track", "simultaneous_block", "BlockOptions", "least_squares",
            "Observations", "RankDeficiencyError", "GeometryError", "SeaiceError", "MapGrid", "Projection",
            "NavigationSpline", "Trajectory", "simulate_sequence", "nsidc_polar_stereographic"} <= set(names)
    # readers first, errors last
    assert names[0].startswith("read_") and names[-1].endswith("Error")
    script = ("import sys, seaice_jax as sj\n"
              "heavy = [m for m in ('cv2', 'matplotlib', 'xarray') if m in sys.modules]\n"
              "assert not heavy, heavy\n"
              f"missing = [n for n in {names!r} if getattr(sj, n, None) is None]\n"
              "assert not missing, missing\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            env={**os.environ, "JAX_PLATFORMS": "cpu"})
    assert result.returncode == 0, result.stderr[-2000:]
