"""What an L-system amounts to, counted through its grammar and scene graph (the CLI's
`lsystem` report and the Blender panel's statistics).

Counts come from `lsystem.count` (memoised per module and remaining steps) and
primitives from the DCSG, so both work for grammars far too large to derive.
Bounds are the turtle's (start point and every segment's end point, in the
turtle frame): exact from the derived string while that is small enough, else
the scene graph's box, which also holds the primitives' extents and is marked
`bounds_exact: false`.
"""
import time

from .geometry import dcsg
from .lsystem.grammar import format_string
from .lsystem import derivation
from .lsystem import turtle

# Derive (for exact bounds and --string) up to this many modules.
DERIVE_LIMIT = 2_000_000
# Cycles builds one object per instance: the memory a render adds per instance,
# measured by benchmarks/bench_cycles_instances.py with bpy 5.0.1 (1 363 bytes;
# tests/data/cycles_instances.json keeps that run).
CYCLES_BYTES_PER_INSTANCE = 1360
CYCLES_MAX_NESTING = 6


def summary(grammar, steps=None, with_string=False):
    """A JSON-ready dict: length, counts, segments, bounds, primitives, dcsg_nodes,
    memory (graph bytes and what flattening would cost), timings (s)."""
    t0 = time.perf_counter()
    counts = derivation.count(grammar, steps)
    t_count = time.perf_counter() - t0
    out = {"grammar": grammar.source_name,
           "steps": grammar.derivation_length if steps is None else int(steps),
           "length": counts.length, "counts": dict(sorted(counts.per_symbol.items())),
           "counts_exact": counts.exact, "segments": counts.per_symbol.get("F", 0)}
    timings = {"count": t_count}
    graph = None
    t0 = time.perf_counter()
    try:
        graph = dcsg.DCSG(grammar, steps)
    except dcsg.DCSGUnsupported as exc:
        out["dcsg"] = f"not a scene graph: {exc}"
    timings["dcsg"] = time.perf_counter() - t0
    small = counts.length <= DERIVE_LIMIT
    if small or graph is None:
        t0 = time.perf_counter()
        der = derivation.derive(grammar, steps, cap=max(DERIVE_LIMIT, derivation.DEFAULT_CAP))
        timings["derive"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        geom = turtle.interpret(der.modules, grammar.angle, grammar.width)
        timings["turtle"] = time.perf_counter() - t0
        out["bounds"] = {"min": geom.bounds[0].tolist(), "max": geom.bounds[1].tolist()}
        out["bounds_exact"] = True
        if with_string:
            out["string"] = format_string(der.modules)
        if graph is None:
            prims = turtle.to_primitives(geom)
            out["primitives"] = len(prims)
    else:
        lo, hi = graph.bounds()
        out["bounds"] = {"min": lo.tolist(), "max": hi.tolist()}
        out["bounds_exact"] = False
        if with_string:
            out["string"] = (f"not derived: {counts.length:,} modules (more than "
                             f"{DERIVE_LIMIT:,}); the scene graph traces it without a string")
    if graph is not None:
        st = graph.stats()
        out["primitives"] = st["primitives"]
        out["dcsg_nodes"] = st["dcsg_nodes"]
        out["dcsg"] = {k: st[k] for k in ("alternatives", "edges", "terminal_primitives", "depth",
                                          "cache_subgraphs", "cache_primitives", "cache_bytes",
                                          "cache_limit_bytes", "cache_hit_rate")}
        out["memory"] = {"dcsg_bytes": st["bytes"]}
    n_prims = out.get("primitives", 0)
    out.setdefault("memory", {})["flattened_in_cycles_bytes"] = int(round(n_prims * CYCLES_BYTES_PER_INSTANCE))
    out["cycles_max_nesting"] = CYCLES_MAX_NESTING
    out["timings"] = timings
    return out
