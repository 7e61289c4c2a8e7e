"""The package as installed: bundled files found through importlib.resources, the sample command, python -m,
--list-params, and a layout without import cycles."""
from __future__ import annotations

import ast
from pathlib import Path

from helpers import run
from vpr_edge.matchers import MATCHERS
from vpr_edge.resources import DEFAULT_MODEL_FILE, SMALL_MODEL_FILE, bundled_model, copy_sample, sample_folder

PACKAGE = Path(__file__).resolve().parent.parent / "vpr_edge"


def test_bundled_files_are_inside_the_package() -> None:
    import vpr_edge

    root = Path(vpr_edge.__file__).parent
    for name in (DEFAULT_MODEL_FILE, SMALL_MODEL_FILE):
        assert bundled_model(name).is_file() and bundled_model(name).parent.parent == root
    sample = sample_folder()
    assert sample.parent.parent == root
    assert len(list((sample / "ref").glob("*.jpg"))) == len(list((sample / "query").glob("*.jpg"))) == 111
    assert (sample / "ground_truth.csv").read_text().count("\n") == 112


def test_sample_copies_what_it_names_where_it_says(tmp_path: Path) -> None:
    """``vpr-edge sample corridor`` makes ./corridor holding the Corridor sample and says so in one line; --to
    names another folder; a name that is no bundled sample is refused before anything is written."""
    proc = run("sample", "corridor", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ("copied the bundled sample corridor (the Corridor dataset, Milford 2013: 111 reference "
                           "and 111 query frames, 160x120) to corridor/: ref/ (111 frames), query/ (111 frames), "
                           "ground_truth.csv, positions.csv (synthetic, see ReadMe.txt)\n")
    copied = sorted(p.name for p in (tmp_path / "corridor").iterdir())
    assert copied == sorted(p.name for p in sample_folder().iterdir())
    proc = run("sample", "corridor", "--to", "mine", cwd=tmp_path)
    assert proc.returncode == 0 and "to mine/:" in proc.stderr, proc.stderr
    assert len(list((tmp_path / "mine" / "query").iterdir())) == 111
    for args in (["nordland"], ["nordland", "--to", "n"]):
        proc = run("sample", *args, cwd=tmp_path)
        assert proc.returncode == 2 and proc.stderr == "vpr-edge: error: unknown sample 'nordland'; choose from " \
            "corridor\n", proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corridor", "mine"]


def test_copy_sample_never_writes_over(tmp_path: Path) -> None:
    out = copy_sample("corridor", tmp_path / "c")
    assert sorted(p.name for p in out.iterdir()) == ["ReadMe.txt", "ground_truth.csv", "positions.csv", "query",
                                                     "ref"]
    before = sorted(p.name for p in out.rglob("*"))
    for args, problem in ((["--to", "c"], "already exists"), (["--to", "missing/c"], "does not exist"),
                          (["nope", "--to", "d"], "unknown sample")):
        proc = run("sample", *args, cwd=tmp_path)
        assert proc.returncode == 2 and problem in proc.stderr, proc.stderr
        assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert sorted(p.name for p in out.rglob("*")) == before and not (tmp_path / "d").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]     # no temporary copy left behind


def test_python_m_and_list_params(tmp_path: Path) -> None:
    import vpr_edge

    version = run("--version", cwd=tmp_path)
    assert version.returncode == 0 and version.stdout.strip() == f"vpr-edge {vpr_edge.__version__}"
    listed = run("localize", "--list-params", cwd=tmp_path)
    assert listed.returncode == 0
    for m in MATCHERS.values():
        assert listed.stdout.count(f"\n{m.name} (") + listed.stdout.startswith(f"{m.name} (") == 1
        for key, value in m.params.items():
            assert f"  {key} = {value!r}: {m.definitions[key].meaning}" in listed.stdout
    assert run("evaluate", "--list-params").stdout == listed.stdout


def test_every_parameter_is_defined_once_and_constructors_take_them() -> None:
    for m in MATCHERS.values():
        assert set(m.params) == set(m.definitions)
        m.run(__import__("numpy").random.default_rng(0).random((6, 5)), 1)   # the presets construct and run


def test_no_parameter_default_is_repeated_in_a_signature() -> None:
    """A matcher parameter's default lives in ``matchers.params`` alone: neither a matcher's entry point
    (``align``, ``start``) nor any function or class of the modules that implement the parameter tables'
    matchers gives a parameter of that name a keyword default of its own (it would drift from the table)."""
    import importlib
    import inspect

    from vpr_edge.matchers import params as P

    def defaulted(obj: object, names: set[str]) -> list[str]:
        try:
            signature = inspect.signature(obj)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return []
        return [f"{getattr(obj, '__qualname__', obj)}({name}={p.default!r})" for name, p in signature.parameters.items()
                if name in names and p.default is not inspect.Parameter.empty]

    repeated = [hit for m in MATCHERS.values() for entry in (m.align, m.start) if entry is not None
                for hit in defaulted(entry, set(m.definitions))]
    # contrast's ``window`` is seqslam's ``r_window`` by its own name
    for module, names in (("dtw", set(P.DTW)), ("seqslam", set(P.SEQSLAM)), ("contrast", {"window"})):
        mod = importlib.import_module(f"vpr_edge.matchers.{module}")
        for obj in vars(mod).values():
            if (inspect.isfunction(obj) or inspect.isclass(obj)) and obj.__module__ == mod.__name__:
                repeated += defaulted(obj, names)
    assert not repeated, f"defaults repeated outside matchers/params.py: {repeated}"


def _imports(path: Path) -> list[tuple[str, str | None]]:
    """(module, name) for each ``from vpr_edge... import name`` and (module, None) for each ``import vpr_edge...``
    in ``path``, anywhere in it (lazy imports inside functions too)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and node.module.startswith("vpr_edge"):
            found += [(node.module, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(a.name, None) for a in node.names if a.name.startswith("vpr_edge")]
    return found


def test_no_import_cycles() -> None:
    """Module A imports B (at the top or inside a function) and B, directly or not, imports A: refused. Names
    taken from a package (``from vpr_edge.map import load_map``) count as imports of the modules its
    __init__ takes them from; the package root is left out (it re-exports the API lazily)."""
    def dotted(path: Path) -> str:
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        return ".".join(("vpr_edge",) + (parts[:-1] if parts[-1] == "__init__" else parts))

    files = {dotted(p): p for p in PACKAGE.rglob("*.py") if p.name != "__main__.py" and p != PACKAGE / "__init__.py"}
    packages = {dotted(p) for p in PACKAGE.rglob("__init__.py")}

    def targets(module: str, name: str | None) -> set[str]:
        if name is not None and f"{module}.{name}" in files:
            return {f"{module}.{name}"}
        return {module} if module in files else set()

    graph = {m: set().union(*[targets(a, b) for a, b in _imports(p)]) - {m} for m, p in files.items()}

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            node = todo.pop()
            if node == goal:
                return True
            if node not in seen:
                seen.add(node)
                todo.extend(graph[node])
        return False

    assert packages and graph
    cycles = sorted(f"{a} <-> {b}" for a in graph for b in graph[a] if reaches(b, a))
    assert not cycles, cycles


def test_no_test_module_imports_another() -> None:
    """Each test module runs (or skips) on its own: what modules share comes from ``helpers`` (and fixtures from
    conftest), never from another test module, whose skip (a missing extra) would skip the importer too."""
    tests = Path(__file__).resolve().parent
    names = {p.stem for p in tests.glob("*.py")}
    wrong = []
    for path in sorted(tests.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            found = [node.module or ""] if isinstance(node, ast.ImportFrom) else \
                [a.name for a in node.names] if isinstance(node, ast.Import) else []
            for module in found:
                head = module.split(".")[0]
                if head == "tests" or (head in names and (head.startswith("test_") or head == "conftest")):
                    wrong.append(f"{path.name}: {module}")
    assert not wrong, wrong


def test_docstrings_name_only_what_exists() -> None:
    """Every ``module.name`` a docstring or comment of the package or of the lab beside it (vpr_edge_bench)
    cites, whose first part is a module of either, resolves (a renamed or removed module leaves no stale
    pointer)."""
    import importlib
    import pkgutil
    import re

    import vpr_edge
    import vpr_edge_bench

    root = Path(vpr_edge.__file__).parent
    modules = {m.name.rsplit(".", 1)[-1]: m.name for m in pkgutil.walk_packages(vpr_edge_bench.__path__,
                                                                                 "vpr_edge_bench.")}
    modules.pop("__main__", None)   # running it runs the experiments' runner
    modules |= {m.name.rsplit(".", 1)[-1]: m.name for m in pkgutil.walk_packages(vpr_edge.__path__, "vpr_edge.")}
    modules["vpr_edge"] = "vpr_edge"

    def resolves(ref: str) -> bool:
        head, *rest = ref.split(".")
        obj = importlib.import_module(modules[head])
        for part in rest:
            if hasattr(obj, part):
                obj = getattr(obj, part)
                continue
            try:
                obj = importlib.import_module(f"{obj.__name__}.{part}")
            except (ImportError, AttributeError):
                return False
        return True

    files = [*root.rglob("*.py"), *Path(vpr_edge_bench.__file__).parent.rglob("*.py")]
    cited = {ref for f in files for ref in re.findall(r"``([A-Za-z_][\w]*(?:\.[A-Za-z_]\w*)+)``", f.read_text())}
    files_named = {"csv", "json", "npz", "npy", "onnx", "jpg", "png", "gpx", "bag", "mcap", "h5", "yaml"}
    stale = sorted(ref for ref in cited if ref.split(".")[0] in modules and ref.rsplit(".", 1)[-1] not in files_named
                   and not resolves(ref))
    assert not stale, stale


def test_matcher_constants_are_named_in_one_place() -> None:
    """No module of ``vpr_edge/matchers`` but ``constants`` (the models' numbers) and ``params`` (what a user sets)
    names a number at module level: a constant of a matcher's model is found in one file."""
    def numeric(node: ast.AST) -> bool:
        if isinstance(node, ast.Constant):
            return isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
        if isinstance(node, ast.UnaryOp):
            return numeric(node.operand)
        if isinstance(node, ast.Tuple):
            return any(numeric(e) for e in node.elts)
        return False

    found = []
    for path in sorted((PACKAGE / "matchers").glob("*.py")):
        if path.name in ("constants.py", "params.py"):
            continue
        for node in ast.parse(path.read_text()).body:
            value = node.value if isinstance(node, (ast.Assign, ast.AnnAssign)) else None
            if value is not None and numeric(value):
                found.append(f"{path.name}:{node.lineno}")
    assert not found, found
