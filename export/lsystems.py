"""L-system objects (Add > Photon L-System) -> engine `LSystem` prototypes, and what the
authoring side (bake/lsystem_preview.py, operators/lsystem.py, ui/) shares with the export:
where the grammar is stored, the object settings' defaults, parsing with the overrides and
the statistics. The preview itself (plan, node group, realized mesh) is
bake/lsystem_preview.py.

Conventions (docs/architecture.md, "L-system objects"):

* An *L-system object* is a mesh object whose custom property ``ob["photon_lsys_text"]``
  points at a Text datablock holding the grammar (engine/lsystem/grammar.py format). Its Geometry
  Nodes modifier's group carries the same pointer and a copy of ``ob["photon_lsys"]``
  (``INFO_PROP``): ``{"version", "hash" (of the text last previewed), "checked" (of the
  text last looked at, valid or not), "path", "depth", "symbols", "note", "stats"}``.
  Both are ID properties, so they survive save, reload and library linking; the grammar
  text is the source of truth, the node group is generated from it for the viewport only.
* Object-level settings are `Object.photon_lightmaps.lsystem` (ui/properties.py), whose
  defaults are `LSystemSettings` below (one copy).
* Export: the object's own depsgraph entry becomes ``Prototype(lsystems=[LSystem(...)])``
  plus an `Instance` at the object's world matrix; everything its modifier generates (the
  preview meshes, their instances, organ instances) and its own evaluated mesh are skipped.
  The engine traces the grammar at the render depth; ``;(i)`` selects material slot i.

Nothing here imports bpy, nor the numba kernels of engine/geometry/dcsg.py (and so
engine/lsystem_stats.py) at module level (importing `export` stays light).
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, fields, replace

import numpy as np

from ..engine.lsystem import grammar
from ..engine.lsystem.grammar import LSystemError
from ..engine.lsystem import derivation
from ..engine.core.scene import LSystem, Prototype, SceneError
from .context import PrototypeRecord
from .materials import material

TEXT_PROP = "photon_lsys_text"
INFO_PROP = "photon_lsys"
FORMAT_VERSION = 1
MODIFIER_NAME = "Photon L-System"
# Blender shows at most 6 nested instance levels (object_dupli.cc, MAX_DUPLI_RECUR); deeper
# levels are dropped from the viewport and from Cycles. The preview never goes deeper.
MAX_PREVIEW_DEPTH = 6
# Modules a grammar without a scene graph may derive for the panel's statistics.
STATS_MODULE_CAP = 2_000_000

# ABOP fig. 1.24a, for when engine/lsystem/presets is not available.
FALLBACK_PRESET = "abop_1_24a"
FALLBACK_PRESET_LABEL = "ABOP 1.24a (bracketed plant)"
FALLBACK_PRESET_TEXT = """\
# ABOP fig. 1.24a: a bracketed OL-system (edge rewriting)
axiom: F
derivation length: 5
angle: 25.7
production:
F --> F[+F]F[-F]F
"""


def presets():
    """[(name, label, description)] of the grammar presets (engine/lsystem/presets, or the
    one built-in fallback when that package is not there)."""
    try:
        from ..engine.lsystem import presets as P
        out = [(name, label, desc) for name, (label, desc) in P.PRESETS.items()]
        if out:
            return out
    except (ImportError, AttributeError):
        pass
    return [(FALLBACK_PRESET, FALLBACK_PRESET_LABEL, "ABOP fig. 1.24a: F --> F[+F]F[-F]F, 25.7 degrees")]


def preset_text(name):
    """The grammar text of a preset (the fallback's for an unknown name without presets)."""
    try:
        from ..engine.lsystem import presets as P
        if name in P.PRESETS:
            return P.preset_text(name)
    except (ImportError, AttributeError):
        pass
    if name == FALLBACK_PRESET:
        return FALLBACK_PRESET_TEXT
    raise SceneError(f"L-system preset '{name}': unknown (known: {', '.join(n for n, _, _ in presets())})")


# ---------------------------------------------------------------- settings

@dataclass(frozen=True)
class LSystemSettings:
    """An L-system object's settings; the defaults of `Object.photon_lightmaps.lsystem`."""
    use_render_iterations: bool = False     # off: the grammar's derivation length
    render_iterations: int = 5
    preview_iterations: int = MAX_PREVIEW_DEPTH     # capped at the render depth
    use_seed: bool = False                  # off: the grammar's seed
    seed: int = 0
    use_angle: bool = False                 # off: the grammar's angle
    angle: float = 25.7                     # degrees
    cache_mb: float = 64.0                  # the engine's expansion cache (engine/geometry/dcsg.py)

    @classmethod
    def read(cls, props, **overrides):
        if props is None:
            return replace(cls(), **overrides)
        vals = {f.name: getattr(props, f.name) for f in fields(cls) if hasattr(props, f.name)}
        vals.update(overrides)
        return cls(**vals)

    @property
    def steps(self):
        return int(self.render_iterations) if self.use_render_iterations else None

    @property
    def seed_override(self):
        return int(self.seed) if self.use_seed else None

    @property
    def angle_override(self):
        return float(self.angle) if self.use_angle else None


def settings_of(ob):
    ob = getattr(ob, "original", None) or ob
    props = getattr(getattr(ob, "photon_lightmaps", None), "lsystem", None)
    return LSystemSettings.read(props)


# ---------------------------------------------------------------- storage

def _is_text(v):
    return v is not None and hasattr(v, "as_string") and hasattr(v, "lines")


def lsystem_modifier(ob):
    """The object's Photon L-System Geometry Nodes modifier (None if it has none)."""
    for m in getattr(ob, "modifiers", ()):
        if m.type == "NODES" and m.node_group is not None and INFO_PROP in m.node_group.keys():
            return m
    return None


def grammar_text(ob):
    """The Text datablock holding an object's grammar, None if it is not an L-system object."""
    if ob is None:
        return None
    ob = getattr(ob, "original", None) or ob
    try:
        t = ob.get(TEXT_PROP)
    except (AttributeError, TypeError):
        return None
    if _is_text(t):
        return t
    if ob.get(INFO_PROP) is None:       # the cheap answer for every other depsgraph entry
        return None
    mod = lsystem_modifier(ob) if ob.type == "MESH" else None
    t = mod.node_group.get(TEXT_PROP) if mod is not None else None
    return t if _is_text(t) else None


def is_lsystem(ob):
    """An object made by Add > Photon L-System (or carrying a grammar text), even if its
    Text was deleted since: its preview is then still not exported as a mesh."""
    if ob is None:
        return False
    ob = getattr(ob, "original", None) or ob
    try:
        if ob.get(INFO_PROP) is not None:
            return True
    except (AttributeError, TypeError):
        return False
    return grammar_text(ob) is not None


def text_hash(s):
    return hashlib.sha1(s.encode("utf-8")).hexdigest()[:16]


def info(ob):
    """The object's `photon_lsys` dict as plain Python (empty if none)."""
    ob = getattr(ob, "original", None) or ob
    d = ob.get(INFO_PROP) if ob is not None else None
    return d.to_dict() if hasattr(d, "to_dict") else dict(d or {})


_HEADER = re.compile(r"^(\s*)([A-Za-z][A-Za-z ]*?)\s*:")


def with_angle(text, angle):
    """`text` with its `angle:` header set to `angle` degrees. An existing header line is
    replaced in place; otherwise the first blank header line takes it, or a new line goes
    before `production:`. Line numbers of the productions stay unchanged where a header line
    or a blank one was there to reuse."""
    if angle is None:
        return text
    lines = text.split("\n")
    new = f"angle: {float(angle)!r}"
    blank = prod = None
    for i, raw in enumerate(lines):
        s = raw.split("#", 1)[0]
        m = _HEADER.match(s)
        key = " ".join(m.group(2).lower().split()) if m else None
        if key in ("production", "productions"):
            prod = i
            break
        if s.strip().lower() == "endlsystem":
            break
        if key == "angle":
            lines[i] = m.group(1) + new
            return "\n".join(lines)
        if not s.strip() and blank is None and not raw.strip():
            blank = i
    if blank is not None:
        lines[blank] = new
    elif prod is not None:
        lines.insert(prod, new)
    else:
        lines.append(new)
    return "\n".join(lines)


def effective_text(text, settings):
    """The grammar text the engine receives: the angle override written into it (the
    engine's LSystem carries steps and seed, not the angle)."""
    return with_angle(text, settings.angle_override)


def parse(text, name, settings):
    """(user's Grammar, effective Grammar): the user's text is parsed first, so a syntax
    error names its own line and column; the effective one carries the overrides."""
    user = grammar.parse(text, name=name)
    eff = grammar.parse(effective_text(text, settings), name=name) if settings.use_angle else user
    if settings.seed_override is not None:
        eff = replace(eff, seed=settings.seed_override)
    return user, eff


def render_steps(grammar, settings):
    """Derivation steps a render traces (None when a grammar without a derivation length
    cannot be shown to stop)."""
    if settings.steps is not None:
        return settings.steps
    if grammar.derivation_length is not None:
        return grammar.derivation_length
    try:
        return derivation.check_termination(grammar)
    except LSystemError:
        return None


def preview_depth(grammar, settings):
    """min(preview iterations, render depth, MAX_PREVIEW_DEPTH)."""
    d = min(int(settings.preview_iterations), MAX_PREVIEW_DEPTH)
    steps = render_steps(grammar, settings)
    return max(0, d if steps is None else min(d, steps))


def organ_names(text):
    """Organ names `~(name, ...)` the grammar text mentions, in order of appearance."""
    out = []
    for line in text.splitlines():
        for m in re.finditer(r"~\(\s*(\"[^\"]*\"|'[^']*'|[A-Za-z_]\w*)", line.split("#", 1)[0]):
            n = m.group(1).strip("\"'")
            if n not in out:
                out.append(n)
    return out


def ol_stub_lines(grammar):
    return [s.symbol + ("" if s.levels is None else f" (levels {', '.join(map(str, s.levels))})")
            for s in grammar.ol_stubs]


# ---------------------------------------------------------------- statistics

def statistics(grammar, steps, cache_mb=LSystemSettings.cache_mb):
    """What the engine makes of the grammar at `steps` (None: its own derivation length):
    {"primitives", "exact", "dcsg_nodes", "graph_bytes", "depth", "steps", "flat_bytes",
    "graph"}. The figures are the engine's: `DCSG.stats()` for a scene graph; a grammar the
    graph refuses (context-sensitive, ...) is derived and its primitives counted by
    `engine.lsystem_stats.summary`, as the engine instances them (graph False; the seeded
    derivation a render traces, so exact). Raises LSystemError / SceneError for a grammar
    the engine would refuse, LSystemGrowthError past STATS_MODULE_CAP modules."""
    from ..engine import lsystem_stats
    from ..engine.geometry.dcsg import DCSG, DCSGUnsupported
    try:
        d = DCSG(grammar, steps=steps, cache_mb=cache_mb)
    except DCSGUnsupported:
        d = None
    if d is not None:       # not summary(): it also derives the string for its bounds (slow)
        s = d.stats()
        prims = float(s["primitives"])
        return {"primitives": prims, "exact": not grammar.is_stochastic, "dcsg_nodes": int(s["dcsg_nodes"]),
                "graph_bytes": float(s["bytes"]), "depth": int(s["depth"]), "steps": int(d.steps),
                "flat_bytes": prims * lsystem_stats.CYCLES_BYTES_PER_INSTANCE, "graph": True,
                "cache_subgraphs": int(s["cache_subgraphs"]), "cache_bytes": float(s["cache_bytes"]),
                "cache_hit_rate": float(s["cache_hit_rate"])}
    derivation.count(grammar, steps, cap=STATS_MODULE_CAP)      # the panel's cap, before summary derives
    s = lsystem_stats.summary(grammar, steps)
    return {"primitives": float(s["primitives"]), "exact": True, "dcsg_nodes": 0, "graph_bytes": 0.0,
            "depth": 0, "steps": -1 if s["steps"] is None else int(s["steps"]),
            "flat_bytes": float(s["memory"]["flattened_in_cycles_bytes"]), "graph": False}


def __getattr__(name):
    """CYCLES_BYTES_PER_INSTANCE is engine/lsystem_stats.py's (one copy), read on first use
    so that importing this module does not import the numba kernels."""
    if name == "CYCLES_BYTES_PER_INSTANCE":
        from ..engine.lsystem_stats import CYCLES_BYTES_PER_INSTANCE
        return CYCLES_BYTES_PER_INSTANCE
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# ---------------------------------------------------------------- export

def organ_resolver(ob):
    """`~(name)` -> the object of that name in the organ collection (or anywhere), else the
    child collection (or any collection) of that name."""
    import bpy
    props = ob.photon_lightmaps.lsystem
    coll = props.organs

    def resolve(name):
        if coll is not None:
            o = coll.all_objects.get(name)
            if o is not None:
                return o
            if coll.name == name:
                return coll
            c = coll.children_recursive
            c = next((x for x in c if x.name == name), None)
            if c is not None:
                return c
        o = bpy.data.objects.get(name)
        if o is not None and o != ob:
            return o
        return bpy.data.collections.get(name)
    return resolve


def organ_meshes(ctx, ob, text):
    """name -> TriangleMesh (the organ's evaluated geometry in its own frame, as the
    preview instances it: an object's local mesh, or a collection's objects' local
    meshes together) for every organ the grammar names; a name that resolves to no
    mesh is reported and drawn as nothing."""
    import bpy
    from ..engine.core.scene import TriangleMesh
    from .meshes import leaf_mesh
    resolve = organ_resolver(ob)
    out = {}
    for name in dict.fromkeys(organ_names(text)):
        target = resolve(name)
        objs = ([o for o in target.all_objects] if isinstance(target, bpy.types.Collection)
                else [target] if target is not None else [])
        parts = []
        for o in objs:
            ev = o.evaluated_get(ctx.dg) if ctx.dg is not None else o
            try:
                me = ev.to_mesh()
            except RuntimeError:
                me = None
            if me is not None:
                tm = leaf_mesh(ctx, me, o)
                if tm is not None:
                    parts.append(tm)
                ev.to_mesh_clear()
        if not parts:
            ctx.report("WARNING", f"L-system object '{ob.name}': organ '{name}' has no mesh (set the "
                                   "Organs collection or add an object of that name); it is not drawn")
            continue
        v0 = np.cumsum([0] + [p.vertices.shape[0] for p in parts])
        out[name] = TriangleMesh(np.concatenate([p.vertices for p in parts]),
                                 np.concatenate([p.triangles + v for p, v in zip(parts, v0)]),
                                 material=parts[0].material, name=name)
    return out

def is_preview(original, parent):
    """True for depsgraph entries an L-system object's modifier generates (its preview
    geometry, their instances, organ instances): the engine traces the grammar instead."""
    if parent is not None and parent.original is not None and is_lsystem(parent.original):
        return True
    return parent is not None and is_lsystem(original)


def lsystem_prototype(ctx, ob):
    """Prototype index of an L-system object's grammar, -1 if it cannot be exported
    (reported). Objects sharing the Text, settings and materials share the prototype."""
    original = getattr(ob, "original", None) or ob
    name = original.name
    text = grammar_text(original)
    if text is None:
        ctx.report("WARNING", f"L-system object '{name}' has no grammar Text (it was deleted?); "
                               "it is not exported")
        return -1
    settings = settings_of(original)
    slots = [s.material for s in ob.material_slots] or [s.material for s in original.material_slots]
    mats = tuple(material(ctx, m) for m in slots) or (material(ctx, None),)
    # objects with the same grammar, settings and materials share one prototype
    key = ("lsystem", text.as_pointer(), settings, mats)
    idx = ctx.prototype_index.get(key)
    if idx is not None:
        return idx
    ctx.prototype_index[key] = -1
    src = text.as_string()
    try:
        parse(src, text.name, settings)
    except LSystemError as exc:
        ctx.report("WARNING", f"L-system object '{name}': {' '.join(str(exc).split())}; it is not exported")
        return -1
    lsys = LSystem(grammar=effective_text(src, settings), name=name, steps=settings.steps,
                   seed=settings.seed_override, materials=mats, cache_mb=float(settings.cache_mb),
                   organs=organ_meshes(ctx, original, src))
    ctx.scene.prototypes.append(Prototype(name=name, lsystems=[lsys]))
    ctx.map.prototypes.append(PrototypeRecord(name, 0, "lsystem"))
    idx = ctx.prototype_index[key] = len(ctx.scene.prototypes) - 1
    return idx
