"""The package's import layers, read from the source with ``ast`` (nothing is imported), so that the data flow
reads in one direction. From the bottom:

0. ``params``: the parameter sets, and the package root (``vswrist_gym/__init__.py``: the registry of
   environment ids, which names its entry points as strings);
1. the analytic model: ``kinematics``, ``stiffness`` (NumPy only);
2. ``model/``: the MuJoCo model built from the parameters, the compiled plugins and advance (``native``,
   ``plugin_lib``, ``advance_lib``), export;
3. the simulator: ``sim`` (one world) and ``batch_sim`` (many worlds through the compiled advance);
4. the controller and what runs it without an environment: ``control``, ``paper_trial`` (the paper's Fig. 3c
   trial), ``identify`` (the identification from the paper's four numbers);
5. ``envs/``: the Gymnasium environments, single and batched;
6. ``agents/``: the analytic baseline, training, evaluation, run directories, the shipped policies' lookup;
7. ``tools/``, ``sweep/``, ``cli``, ``pretrained`` (the shipped policies' folders): commands.

A module may import its own layer and the ones below. Every import counts, also one inside a function
(it runs the same code, only later). Beyond the layers: no cycle between modules, and an environment reaches
the physics through the simulator's interface, not through the compiled libraries' modules or raw MuJoCo
addresses (``_address``)."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "vswrist_gym"

LAYERS = (
    ("params", ("vswrist_gym", "vswrist_gym.params")),
    ("analytic model", ("vswrist_gym.kinematics", "vswrist_gym.stiffness")),
    ("model", ("vswrist_gym.model",)),
    ("sim", ("vswrist_gym.sim", "vswrist_gym.batch_sim")),
    ("control", ("vswrist_gym.control", "vswrist_gym.paper_trial", "vswrist_gym.identify")),
    ("envs", ("vswrist_gym.envs",)),
    ("agents", ("vswrist_gym.agents",)),
    ("tools", ("vswrist_gym.tools", "vswrist_gym.sweep", "vswrist_gym.cli", "vswrist_gym.pretrained")),
)
ENV_FORBIDDEN = ("vswrist_gym.model.advance_lib", "vswrist_gym.model.plugin_lib")


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _targets(module: str, path: Path, node: ast.AST) -> list[str]:
    """The package's modules an import statement names (``from a import b``: a.b where that is a module)."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            here = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
            anchor = here[:len(here) - node.level + 1]
            base = ".".join(anchor + ([base] if base else []))
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
    out = []
    for name in names:
        while name and name not in MODULES:
            name = name.rpartition(".")[0]
        if name and name != module:
            out.append(name)
    return out


def _graph() -> dict[str, dict[str, int]]:
    """{module: {imported module: line of the first such import}}."""
    graph = {}
    for module, path in MODULES.items():
        edges: dict[str, int] = {}
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target in _targets(module, path, node):
                    edges.setdefault(target, node.lineno)
        graph[module] = edges
    return graph


def layer(module: str) -> int:
    """The index in LAYERS of the longest prefix naming ``module`` (KeyError: a module no layer holds)."""
    best, depth = None, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > depth:
                best, depth = i, len(p)
    if best is None:
        raise KeyError(module)
    return best


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set = set()
    out = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_the_graph_reader_sees_relative_absolute_and_local_imports():
    """The reader's own check, on modules whose imports are known: ``envs.base`` imports ``..sim`` (relative),
    ``agents.evaluate`` imports inside functions, ``sim`` imports ``.model.builder``."""
    g = _graph()
    assert "vswrist_gym.sim" in g["vswrist_gym.envs.base"]
    assert "vswrist_gym.model.builder" in g["vswrist_gym.sim"]
    assert "vswrist_gym.agents.trained" in g["vswrist_gym.agents.runs"]
    assert len(MODULES) > 60


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if not any(m == p or m.startswith(p + ".") for _, ps in LAYERS for p in ps)]
    assert not missing, f"modules in no layer (add them to LAYERS and the docstring): {missing}"


def test_no_import_cycle():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_module_imports_a_higher_layer():
    bad = []
    for module, edges in _graph().items():
        for target, line in edges.items():
            if layer(target) > layer(module):
                bad.append(f"{MODULES[module].relative_to(PACKAGE.parent)}:{line} ({LAYERS[layer(module)][0]}) "
                           f"imports {target} ({LAYERS[layer(target)][0]})")
    assert not bad, "imports of a higher layer:\n" + "\n".join(bad)


def test_environments_reach_the_physics_through_the_simulator():
    bad = []
    for module, edges in _graph().items():
        if layer(module) != layer("vswrist_gym.envs"):
            continue
        path = MODULES[module]
        for target, line in edges.items():
            if target in ENV_FORBIDDEN:
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {target}")
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "_address":
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} reads a raw MuJoCo address")
    assert not bad, "environments past the simulator's interface:\n" + "\n".join(bad)
