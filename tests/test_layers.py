"""The layering of the code base: imports go downward only, no cycles, the runtime never imports
training code or research. Every import statement counts, lazy ones inside functions included."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("live", "drivers", "models", "sim", "research")

#: Lowest first; a module may import its own layer and the layers below it.
LAYERS = (
    ("core", ("live.core", "live")),
    ("drivers", ("drivers",)),
    ("io", ("live.io",)),
    ("motion", ("live.motion",)),
    ("body", ("live.body",)),
    ("skeleton model", ("models.skeleton", "models")),
    ("retarget", ("live.retarget",)),
    ("imu", ("live.imu",)),
    ("outputs", ("live.outputs",)),
    ("pipeline", ("live.pipeline",)),
    ("sim", ("sim",)),
    ("evaluation", ("live.evaluation",)),
    ("app", ("live.app",)),
    ("training", ("models.train",)),
    ("research", ("research",)),
)
RUNTIME_LAYERS = {name for name, _ in LAYERS} - {"training", "research"}


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            mods[name] = path
    return mods


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(name: str, path: Path) -> set[str]:
    """Our modules that ``name`` imports anywhere in its file."""
    found: set[str] = set()
    is_package = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            # ``from pkg import submodule`` imports the submodule, not only the package.
            targets = [module] + [f"{module}.{alias.name}" for alias in node.names]
        else:
            continue
        for target in targets:
            if target.split(".")[0] in PACKAGES:
                resolved = _resolve(target)
                if resolved and resolved != name:
                    found.add(resolved)
    return found


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def layer_of(module: str) -> int:
    best, best_len = -1, -1
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = index, len(prefix)
    assert best >= 0, f"{module} is in no layer: add it to LAYERS"
    return best


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_every_module_has_a_layer():
    for module in MODULES:
        layer_of(module)


def test_no_import_cycles():
    cycles = _cycles(GRAPH)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_imports_go_downward_only():
    upward = [f"{m} ({LAYERS[layer_of(m)][0]}) imports {t} ({LAYERS[layer_of(t)][0]})"
              for m, targets in GRAPH.items() for t in sorted(targets) if layer_of(t) > layer_of(m)]
    assert not upward, "\n".join(upward)


def test_the_core_imports_only_the_core():
    outside = [f"{m} imports {t}" for m, targets in GRAPH.items() if layer_of(m) == 0
               for t in targets if layer_of(t) != 0]
    assert not outside, "\n".join(outside)


def test_only_the_source_registry_imports_drivers_and_sim_together():
    both = [m for m, targets in GRAPH.items() if m.startswith("live.")
            and any(t.startswith("drivers") for t in targets) and any(t.startswith("sim") for t in targets)]
    assert both == ["live.app.sources"]


def test_the_runtime_never_imports_training_code_or_research():
    bad = [f"{m} imports {t}" for m, targets in GRAPH.items() if LAYERS[layer_of(m)][0] in RUNTIME_LAYERS
           for t in targets if LAYERS[layer_of(t)][0] not in RUNTIME_LAYERS]
    assert not bad, "\n".join(bad)


def test_importing_the_runtime_and_the_cli_does_not_import_torch():
    code = ("import sys, importlib\n"
            "for m in ('live.app.cli', 'live.app.commands', 'live.app.tool_commands', 'live.app.assemble',\n"
            "          'live.app.sources', 'live.evaluation.retarget', 'live.evaluation.skeleton', 'sim.synth',\n"
            "          'sim.skeleton_data', 'models.skeleton.runtime', 'live.body.library'):\n"
            "    importlib.import_module(m)\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'anny', 'warp') or m.startswith('models.train'))\n"
            "print(','.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_package_init_files_do_not_import_their_own_submodules():
    # Re-exports in __init__ files make every submodule import its siblings: the root of most cycles.
    offenders = [f"{m} imports {t}" for m, path in MODULES.items() if path.name == "__init__.py"
                 for t in GRAPH[m] if t.startswith(m + ".")]
    assert not offenders, "\n".join(offenders)
