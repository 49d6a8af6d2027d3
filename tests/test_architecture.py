"""The import ranks of docs/architecture.md, checked on the source with `ast` (nothing is imported).

engine < messages < export < bake < operators < ui < top (the package __init__,
registration, cli, __main__, demo_blend): a module imports only from its own
rank or a lower one, nothing under engine/ imports bpy, and no two packages
import each other. Inside the engine, the same for its sub-packages:
core < lsystem < geometry < lightmaps < shading < transport < the pipeline
modules at engine/ itself (compile, session, warmup, ...).
"""
import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RANKS = {"engine": 0, "messages": 1, "export": 2, "bake": 3, "operators": 4, "ui": 5}
TOP = 6
ENGINE_RANKS = {"core": 0, "lsystem": 1, "geometry": 2, "lightmaps": 3, "shading": 4, "transport": 5}
ENGINE_TOP = 6
SKIP = {"tests", "benchmarks", "scripts", "docs", ".venv", "wheels", "dist", "out", "__pycache__"}


def _modules():
    for dirpath, dirnames, filenames in os.walk(ROOT):
        dirnames[:] = [d for d in dirnames if d not in SKIP and not d.startswith(".")]
        for f in filenames:
            if f.endswith(".py"):
                path = os.path.join(dirpath, f)
                yield os.path.relpath(path, ROOT).replace(os.sep, "/"), path


def _unit(rel):
    """'export', 'bake', ... or the module name for top-level modules."""
    head = rel.split("/")[0]
    return head[:-3] if head.endswith(".py") else head


def _rank(unit):
    return RANKS.get(unit, TOP)


def _imports(rel, tree):
    """(line, imported unit of this package, or 'bpy'/'bmesh'/... for outside ones) per import."""
    pkg = rel.split("/")[:-1]            # package path of the module
    if rel.endswith("__init__.py"):
        pkg = rel.split("/")[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if parts[0] == "photon_lightmaps" and len(parts) > 1:
                    yield node.lineno, parts[1], None
                else:
                    yield node.lineno, None, parts[0]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                parts = (node.module or "").split(".")
                if parts[0] == "photon_lightmaps":
                    names = parts[1:2] or [a.name for a in node.names]
                    for n in names:
                        yield node.lineno, n, None
                else:
                    yield node.lineno, None, parts[0]
                continue
            base = pkg[:len(pkg) - (node.level - 1)] if node.level > 1 else pkg
            if node.level - 1 > len(pkg):
                continue
            target = base + (node.module.split(".") if node.module else [])
            if target:
                yield node.lineno, target[0].removesuffix(".py"), None
            else:   # "from . import x" at the package root
                for a in node.names:
                    yield node.lineno, a.name, None


def _edges():
    out = []
    for rel, path in _modules():
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), rel)
        for line, unit, external in _imports(rel, tree):
            out.append((rel, line, _unit(rel), unit, external))
    return out


def test_no_module_imports_from_a_higher_rank():
    bad = [f"{rel}:{line} ({src}, rank {_rank(src)}) imports {dst} (rank {_rank(dst)})"
           for rel, line, src, dst, _ in _edges()
           if dst is not None and _rank(dst) > _rank(src)]
    assert not bad, "\n".join(bad)


def test_engine_never_imports_bpy():
    bad = [f"{rel}:{line} imports {ext}" for rel, line, src, _, ext in _edges()
           if src == "engine" and ext in ("bpy", "bmesh", "mathutils", "gpu", "bpy_extras")]
    assert not bad, "\n".join(bad)


def test_no_import_cycle_between_packages():
    graph = {}
    for _, _, src, dst, _ in _edges():
        if dst is not None and dst != src and src in RANKS and dst in RANKS:
            graph.setdefault(src, set()).add(dst)
    cycles = [(a, b) for a in graph for b in graph[a] if a in graph.get(b, ())]
    assert not cycles, cycles


def test_the_ranks_cover_the_layout():
    # A new package must be given a rank here and in docs/architecture.md.
    packages = {d for d in os.listdir(ROOT) if os.path.isfile(os.path.join(ROOT, d, "__init__.py"))
                and d not in SKIP}
    assert packages <= set(RANKS), packages - set(RANKS)


def _engine_edges():
    """(module, line, its engine unit, imported engine unit) for every import inside
    engine/; a unit is a sub-package, or the module's name at engine/ itself."""
    def unit(parts):               # parts below engine/
        head = parts[0].removesuffix(".py") if parts else ""
        return head if head in ENGINE_RANKS else "pipeline"
    out = []
    for rel, path in _modules():
        parts = rel.split("/")
        if parts[0] != "engine":
            continue
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), rel)
        pkg = parts[1:-1]          # package path below engine/
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level > 0:
                up = node.level - 1
                if up > len(pkg):
                    continue       # above engine/: the rank test above covers it
                base = pkg[:len(pkg) - up] + (node.module.split(".") if node.module else [])
                targets = [base] if base else [[a.name] for a in node.names]
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                targets = [n.split(".")[2:] for n in names if n.startswith("photon_lightmaps.engine.")]
            else:
                continue
            for t in targets:
                out.append((rel, node.lineno, unit(parts[1:]), unit(t)))
    return out


def test_no_engine_module_imports_from_a_higher_engine_rank():
    rank = lambda u: ENGINE_RANKS.get(u, ENGINE_TOP)   # noqa: E731
    edges = _engine_edges()
    assert len(edges) > 200        # the walk sees the engine's imports
    bad = [f"{rel}:{line} ({src}) imports {dst}" for rel, line, src, dst in edges if rank(dst) > rank(src)]
    assert not bad, "\n".join(bad)


def test_the_engine_ranks_cover_its_packages():
    eng = os.path.join(ROOT, "engine")
    packages = {d for d in os.listdir(eng) if os.path.isfile(os.path.join(eng, d, "__init__.py"))}
    assert packages == set(ENGINE_RANKS), packages ^ set(ENGINE_RANKS)
