"""What the viewport preview of an L-system shows, without Blender: the Repeat-Zone plan
of a grammar (`symbol_plan`: one GEOMETRY and one MATRIX item per rewritable symbol), the
engine's own expansion where the plan does not fit (`flat_preview`), and that expansion
realized as mesh arrays (`realize`). bake/lsystem_preview.py turns these into the node
group and the mesh; this module never imports bpy, so the tests check it headless."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..engine.lsystem.grammar import LSystemGrowthError
from ..engine.lsystem import derivation
from ..engine.core.scene import SceneError
from ..engine.lsystem.turtle import TurtleState, to_primitives
from ..export import lsystems


# Rewritable symbols (distinct module and turtle state) the per-symbol Repeat Zone takes.
MAX_PREVIEW_SYMBOLS = 48


# Primitives a flattened preview realizes at most (its depth is lowered to fit).
MAX_PREVIEW_PRIMITIVES = 30_000


SEGMENTS = 12


SPHERE_RINGS = 6


class PlanUnfit(Exception):
    """The grammar does not fit the per-symbol Repeat Zone; the message says why."""


@dataclass
class Drawing:
    """What one module draws in its own (turtle start) frame: an engine primitive kind
    ("cylinder", "frustum", "cone", "sphere", "box"; params (top radius,) for a frustum) or an
    "organ" (params (name,)); `matrix` 4x4 maps the unit shape into the module's frame."""
    kind: str
    params: tuple
    matrix: np.ndarray
    material: int


@dataclass
class Child:
    """One drawn child of a symbol's successor: a rewritable symbol (index) or a constant
    drawing, placed by the product of `factors` (4x4 constants, or int k: the exit matrix
    of symbol k one level down), left to right."""
    symbol: int | None
    drawing: Drawing | None
    factors: tuple


@dataclass
class Symbol:
    module: object                  # lsystem.Module
    state: tuple                    # turtle (width, drawn width, material) it is entered with
    label: str
    initial: list                   # [Drawing] at step 0 (what the module draws itself)
    initial_exit: np.ndarray        # 4x4 turtle after the module at step 0
    children: list                  # [Child] of one rewriting step
    exit: tuple                     # factors: the turtle after one rewriting step


@dataclass
class SymbolPlan:
    symbols: list
    root: list                      # [Child] of the axiom


def _fold(factors):
    """Multiplies adjacent constant factors; drops identities."""
    out = []
    for f in factors:
        if isinstance(f, np.ndarray):
            if out and isinstance(out[-1], np.ndarray):
                out[-1] = out[-1] @ f
            else:
                out.append(f)
        else:
            out.append(f)
    out = [f for f in out if not (isinstance(f, np.ndarray) and np.array_equal(f, np.eye(4)))]
    return tuple(out)


class _Restart(Exception):
    """The grammar changes the width: plan again with exact turtle states."""


class _Planner:
    """Builds a SymbolPlan. Symbols are found breadth first from the axiom; a symbol first
    met at distance j below it is read at levels <= max_depth - j only, so its successor
    must look the same at those levels alone, and one met at max_depth needs no rule."""

    def __init__(self, grammar, max_depth, max_symbols, canonical):
        self.g = grammar
        self.angle, self.width = grammar.angle, grammar.width
        self.max_depth, self.max_symbols = max_depth, max_symbols
        # Without any '!' the width never changes, so every segment is a cylinder of the
        # grammar's width whatever the previous drawn width was: states drop it.
        self.canonical = canonical
        self.exit_memo = {}
        self.term_memo = {}
        self.syms = {}              # (module, state) -> index
        self.plan_syms = []
        self.dist = []
        self.succ = []
        self.queue = []

    def norm(self, st):
        return (st[0], None, st[2]) if self.canonical else st

    def alts(self, m):
        a = self.g.alternatives(m)
        if len(a) > 1:
            raise PlanUnfit(f"module {m} has {len(a)} stochastic alternatives (Geometry Nodes cannot "
                            "choose per branch)")
        return a

    def terminal(self, m, st):
        """(drawings, exit 4x4, exit state) of module m at step 0 entered with state st."""
        key = (m, st)
        r = self.term_memo.get(key)
        if r is None:
            if m.symbol == "!" and self.canonical:
                raise _Restart()
            ts = TurtleState(self.angle, self.width)
            ts.width, ts.drawn, ts.material = st
            ts.apply(m)
            geom = ts.geometry()
            draws = []
            for p in to_primitives(geom):
                full = np.eye(4)
                full[:3] = np.asarray(p.transform, np.float64)[:3]
                draws.append(Drawing(p.kind, tuple(p.params), full, int(p.material)))
            for o in geom.organs:
                draws.append(Drawing("organ", (o.name,), np.asarray(o.matrix, np.float64), int(o.material)))
            r = self.term_memo[key] = (draws, ts.matrix(), self.norm((ts.width, ts.drawn, ts.material)))
        return r

    def exit_state(self, m, st, k):
        a = self.alts(m) if k > 0 else []
        if not a:
            return self.terminal(m, st)[2]
        key = (m, st, k)
        r = self.exit_memo.get(key)
        if r is None:
            if len(self.exit_memo) > 20_000:
                raise PlanUnfit("too many distinct modules for a per-symbol preview")
            r = self.exit_memo[key] = self.children(a[0][0].apply(m), st, k - 1)[1]
        return r

    def children(self, succ, st, k):
        """[(module, entry state)] of the non-bracket modules of `succ` entered with st, their
        successors at step k, and the state after them."""
        out, stack = [], []
        for c in succ:
            if c.symbol == "[":
                stack.append(st)
            elif c.symbol == "]":
                if not stack:
                    raise PlanUnfit("unmatched ']'")
                st = stack.pop()
            else:
                if c.symbol == "!" and self.canonical:
                    raise _Restart()
                out.append((c, st))
                st = self.exit_state(c, st, k)
        return out, st

    def uniform_children(self, succ, st, levels, what):
        ref = None
        for k in levels:
            ch, _ = self.children(succ, st, k)
            if ref is None:
                ref = ch
            elif ch != ref:
                raise PlanUnfit(f"the turtle state (width or material) inside {what} depends on the "
                                "depth, so one Repeat Zone step cannot stand for every level")
        return ref

    def symbol(self, m, st, dist):
        key = (m, st)
        i = self.syms.get(key)
        if i is not None:
            return i
        if len(self.syms) >= self.max_symbols:
            raise PlanUnfit(f"more than {self.max_symbols} distinct rewritable modules within "
                            f"{self.max_depth} steps (parameters that keep changing)")
        i = self.syms[key] = len(self.plan_syms)
        draws, ex, _ = self.terminal(m, st)
        self.plan_syms.append(Symbol(m, st, str(m), draws, ex, [], (ex,)))
        self.dist.append(dist)
        self.succ.append(self.alts(m)[0][0].apply(m))
        self.queue.append(i)
        return i

    def walk(self, succ, entries, dist):
        """Children and exit factors of a successor whose modules enter with `entries`."""
        from ..engine.geometry.dcsg import M0  # the turtle's start frame; child -> parent is E @ M0
        it = iter(entries)
        F, stack, kids = [M0.copy()], [], []
        for c in succ:
            if c.symbol == "[":
                stack.append(list(F))
                continue
            if c.symbol == "]":
                F = stack.pop()
                continue
            cm, cst = next(it)
            T = _fold(F + [M0])
            if self.alts(cm):
                k = self.symbol(cm, cst, dist)
                kids.append(Child(k, None, T))
                F = list(T) + [k]
            else:
                draws, ex, _ = self.terminal(cm, cst)
                kids.extend(Child(None, d, T) for d in draws)
                F = list(_fold(list(T) + [ex]))
        return kids, _fold(F)

    def build(self):
        start = self.norm((self.width, None, 0))
        axiom = list(self.g.axiom)
        D = self.max_depth
        ref = self.uniform_children(axiom, start, range(0, D + 1), "the axiom")
        root, _ = self.walk(axiom, ref, 0)
        q = 0
        while q < len(self.queue):
            i = self.queue[q]
            q += 1
            s, d = self.plan_syms[i], self.dist[i]
            if d >= D:
                continue            # read at step 0 only: no rule needed
            ref = self.uniform_children(self.succ[i], s.state, range(0, D - d), f"the successor of {s.module}")
            s.children, s.exit = self.walk(self.succ[i], ref, d + 1)
        # Labels: the module, plus #n where one module is entered in several states.
        seen = {}
        for s in self.plan_syms:
            n = seen[s.label] = seen.get(s.label, 0) + 1
            if n > 1:
                s.label = f"{s.label} #{n}"
        return SymbolPlan(self.plan_syms, root)


def symbol_plan(grammar, max_depth=lsystems.MAX_PREVIEW_DEPTH, max_symbols=MAX_PREVIEW_SYMBOLS):
    """The per-symbol Repeat Zone plan of a context-free, deterministic grammar whose
    successors' structure does not depend on the depth, valid for every depth up to
    `max_depth` (every ABOP-style bracketed system; parametric ones whose parameters take
    few values within max_depth steps, such as fractals that scale by a constant). Raises
    PlanUnfit where the grammar does not fit (stochastic, context-sensitive, too many
    distinct modules, width or material changes that leave a successor differently per
    level)."""
    if not grammar.is_context_free:
        raise PlanUnfit("context-sensitive productions do not fit a per-symbol Repeat Zone")
    try:
        return _Planner(grammar, max_depth, max_symbols, canonical=True).build()
    except _Restart:
        return _Planner(grammar, max_depth, max_symbols, canonical=False).build()


def plan_primitives(plan, depth):
    """Engine primitives (organs excluded) the plan draws at `depth` (a self-check against
    DCSG.implicit_primitives)."""
    n = [sum(d.kind != "organ" for d in s.initial) for s in plan.symbols]
    for _ in range(depth):
        n = [sum(n[c.symbol] if c.symbol is not None else int(c.drawing.kind != "organ")
                 for c in s.children) for s in plan.symbols]
    return sum(n[c.symbol] if c.symbol is not None else int(c.drawing.kind != "organ") for c in plan.root)


@dataclass
class FlatPreview:
    """Primitives of the engine's own expansion at the preview depth, in object space."""
    kinds: list                     # engine kind names
    params: np.ndarray              # (n,) frustum top radius (1 for the others)
    transforms: np.ndarray          # (n, 3, 4)
    materials: np.ndarray           # (n,) int slot
    depth: int
    source: str                     # "dcsg" (DCSG.flatten) or "derived" (derive + turtle)


def flat_preview(grammar, depth, limit=MAX_PREVIEW_PRIMITIVES):
    """The engine's expansion at `depth` or, when that exceeds `limit` primitives, at the
    deepest depth below that fits. Raises LSystemError / SceneError as the engine would."""
    from ..engine.geometry.dcsg import DCSG, DCSGUnsupported
    from ..engine.geometry.primitives import KIND_IDS
    names = {v: k for k, v in KIND_IDS.items()}
    for d in range(depth, -1, -1):
        try:
            g = DCSG(grammar, steps=d)
        except DCSGUnsupported:
            g = None
        if g is not None:
            if g.implicit_primitives > limit and d > 0:
                continue
            f = g.flatten(limit=max(limit, 1) * 2)
            return FlatPreview([names[int(k)] for k in f.kind], f.params[:, 0].copy(), f.transform.copy(),
                               f.material.copy(), d, "dcsg")
        try:
            der = derivation.derive(grammar, d, cap=max(limit, 1) * 20)
        except LSystemGrowthError:
            if d > 0:
                continue
            raise
        from ..engine.lsystem.turtle import interpret
        prims = to_primitives(interpret(der.modules, grammar.angle, grammar.width))
        if len(prims) > limit and d > 0:
            continue
        return FlatPreview([p.kind for p in prims],
                           np.array([p.params[0] if p.params else 1.0 for p in prims], np.float64),
                           np.array([np.asarray(p.transform, np.float64)[:3] for p in prims]).reshape(-1, 3, 4),
                           np.array([p.material for p in prims], np.int64), d, "derived")
    raise SceneError("nothing to preview")   # unreachable: depth 0 always returns


def _ring(n, z, r=1.0):
    a = 2.0 * np.pi * np.arange(n) / n
    return np.stack([r * np.cos(a), r * np.sin(a), np.full(n, z)], axis=1)


def _cylinder_template(n=None):
    n = n or SEGMENTS
    v = np.vstack([_ring(n, -1.0), _ring(n, 1.0)])
    i = np.arange(n)
    faces = [[int(a), int((a + 1) % n), int((a + 1) % n + n), int(a + n)] for a in i]
    faces.append([int(a) for a in i[::-1]])        # bottom cap, facing -z
    faces.append([int(a + n) for a in i])          # top cap, facing +z
    return v, faces


def _sphere_template(n=None, rings=None):
    n, rings = n or SEGMENTS, rings or SPHERE_RINGS
    verts = [(0.0, 0.0, -1.0)]
    for k in range(1, rings):
        th = np.pi * k / rings
        verts.extend(_ring(n, -np.cos(th), np.sin(th)).tolist())
    verts.append((0.0, 0.0, 1.0))
    top = len(verts) - 1
    faces = [[0, 1 + (a + 1) % n, 1 + a] for a in range(n)]
    for k in range(rings - 2):
        b = 1 + k * n
        faces.extend([[b + a, b + (a + 1) % n, b + n + (a + 1) % n, b + n + a] for a in range(n)])
    b = 1 + (rings - 2) * n
    faces.extend([[b + a, b + (a + 1) % n, top] for a in range(n)])
    return np.asarray(verts, np.float64), faces


def _box_template():
    v = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return v, faces


def realize(flat):
    """(vertices (V,3), face sizes, face corner vertices, face material, face primitive) of
    a FlatPreview: each primitive's unit shape through its transform."""
    cyl_v, cyl_f = _cylinder_template()
    sph_v, sph_f = _sphere_template()
    verts, sizes, corners, mats, prim = [], [], [], [], []
    base = 0
    templates = {"sphere": (sph_v, sph_f), "box": _box_template(), "tube": (cyl_v, cyl_f)}
    groups = {name: [] for name in templates}
    for i, k in enumerate(flat.kinds):
        groups[k if k in ("sphere", "box") else "tube"].append(i)
    for name, idx in groups.items():
        if not idx:
            continue
        idx = np.asarray(idx)
        tv, tf = templates[name]
        local = np.broadcast_to(tv, (len(idx),) + tv.shape).copy()
        if name == "tube":
            # frustum (and cone: top radius 0) shrinks the top ring; cylinders keep t = 1
            t = np.array([flat.params[i] if flat.kinds[i] == "frustum" else
                          (0.0 if flat.kinds[i] == "cone" else 1.0) for i in idx])
            local[:, SEGMENTS:, :2] *= t[:, None, None]
        xf = flat.transforms[idx]
        world = np.einsum("pij,pvj->pvi", xf[:, :, :3], local) + xf[:, None, :, 3]
        verts.append(world.reshape(-1, 3))
        fs = np.array([len(f) for f in tf])
        fc = np.concatenate([np.asarray(f) for f in tf])
        nv = tv.shape[0]
        offs = base + nv * np.arange(len(idx))
        corners.append((fc[None, :] + offs[:, None]).reshape(-1))
        sizes.append(np.tile(fs, len(idx)))
        mats.append(np.repeat(flat.materials[idx], len(tf)))
        prim.append(np.repeat(idx, len(tf)))
        base += nv * len(idx)
    if not verts:
        z = np.zeros(0, np.int64)
        return np.zeros((0, 3)), z, z, z, z
    return (np.concatenate(verts), np.concatenate(sizes), np.concatenate(corners),
            np.concatenate(mats), np.concatenate(prim))
