"""3D turtle interpretation of an L-system module string (ABOP 1.5).

An L-system (engine/lsystem/grammar.py) rewrites a string of modules; this module
turns the result into geometry the tracer already knows: every drawn segment
becomes an analytic cylinder (or a cone frustum where the width tapers), every
``@O`` a sphere, every ``@B`` a box. Organs (``~``, a named Blender object or
collection) are only placed here; instancing them is the exporter's job. Pure
Python + numpy: it is part of the bpy-free core and needs no kernels.

Input: modules as ``(symbol, params)`` pairs (``lsystem.Module`` or any
2-tuple). Symbols are one character or ``@`` plus one; params are numbers,
except ``~(name[, scale])``. Symbols not listed below are grammar symbols and
are ignored, and so are parameters past those a symbol reads: a grammar may
tag a drawn module, as the sphereflake preset's growing ``@O(r, generation)``.

Turtle frame. Position p, heading H, left L, up U with U = H x L, so (L, U, H)
is a right-handed frame (L x U = H, U x H = L, H x L = U). Start: p = 0,
H = +Z, L = -X, U = -Y. ``matrix()`` is the affine [L U H p] (columns).

Rotations, by the default angle delta or an explicit first parameter (degrees),
all positive rotations by the right-hand rule about the named axis:

======  ===============  ===========================================
symbol  rotation         effect (90 degrees)
======  ===============  ===========================================
``+``   about U, +delta  H turns toward L   (H' = L,  L' = -H)
``-``   about U, -delta  H turns toward -L  (H' = -L, L' = H)
``&``   about L, +delta  H turns toward -U  (H' = -U, U' = H)
``^``   about L, -delta  H turns toward U   (H' = U,  U' = -H)
``\\``   about H, +delta  L turns toward U   (L' = U,  U' = -L)
``/``   about H, -delta  L turns toward -U  (L' = -U, U' = L)
``|``   about U, 180     H' = -H, L' = -L, U unchanged
======  ===============  ===========================================

The "turns toward" wording and the right-hand rule agree for all six symbols
in this frame (U x H = L, L x H = -U, H x L = U), so no convention had to
give way. Note that ABOP's printed R_U(delta), read literally as
[H' L' U'] = [H L U] R_U, turns H toward -L for "+"; implementations differ
there, and this table is what the project specifies. Every rotation re-orthonormalises (Gram-Schmidt on H, L, then
U = H x L), so 10^4 rotations keep the frame orthonormal and right-handed.

Drawing. ``F(l)`` moves by l (default 1) drawing a segment, ``f(l)`` moves
without drawing, ``[`` / ``]`` push / pop the whole state (an unmatched ``]``
is a SceneError naming the module index), ``!(w)`` sets the diameter (default
the ``width`` argument), ``@O(r)`` a sphere of radius r (default half the
diameter), ``@B(s)`` a cube of side s (default the diameter) centred at the
turtle and aligned with its frame (L, U, H), ``;(i)`` the material slot
(default the next slot), ``~(name[, s])`` an organ in the current frame scaled
by s (default 1). Spheres and boxes take the current material and leave the
turtle where it is; a box turns with the turtle (its faces are normal to L, U
and H), so rotations place the sub-cubes of fractals such as the Menger sponge.

Tapering. A segment is a cylinder of the current diameter unless ``!`` changed
the diameter since the previous segment drawn on this branch; then it is a
frustum from that previous diameter (start) to the current one (end). The
previous drawn diameter is part of the pushed state; the first segment starts
at the current diameter.

Speed: one plain Python loop over the modules with scalar float maths (numpy
per small vector would cost more than the maths), arrays built once at the
end. Measured on a busy 2-core machine: 0.35-0.65 million modules/s for
bracketed F/rotation strings, ~0.33 million/s for F-only or rotation-only
strings, ~6 million/s for grammar symbols (tests/test_turtle.py checks
>= 200k/s); to_primitives makes ~100k primitives/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import chain
from typing import NamedTuple

import numpy as np

from ..core.scene import Primitive, SceneError

_INF = math.inf

# One recorded segment row (TurtleState._seg): start(3) end(3) width0 width1
# material frame; frame indexes TurtleState._frames (rows L, U, H), recorded
# once per frame that draws, since runs of F share one.
_ROW = 10


class Organ(NamedTuple):
    name: str
    matrix: np.ndarray      # 4x4: columns L*s, U*s, H*s, position
    material: int


class Spheres(NamedTuple):
    center: np.ndarray      # (m, 3)
    radius: np.ndarray      # (m,)
    material: np.ndarray    # (m,) int


class Boxes(NamedTuple):
    center: np.ndarray      # (m, 3)
    frame: np.ndarray       # (m, 3, 3) columns L, U, H at the box
    size: np.ndarray        # (m,) side length
    material: np.ndarray    # (m,) int


def _no_boxes():
    return Boxes(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0, np.int64))


@dataclass
class TurtleGeometry:
    """What a module string draws; per-segment arrays of length n_segments."""
    seg_start: np.ndarray                 # (n, 3)
    seg_end: np.ndarray                   # (n, 3)
    seg_frame: np.ndarray                 # (n, 3, 3) columns L, U, H
    seg_width0: np.ndarray                # (n,) diameter at the start
    seg_width1: np.ndarray                # (n,) diameter at the end
    seg_material: np.ndarray              # (n,) int slot
    spheres: Spheres
    boxes: Boxes = field(default_factory=_no_boxes)
    organs: list = field(default_factory=list)
    bounds: tuple = field(default_factory=lambda: (np.zeros(3), np.zeros(3)))  # origin + seg_end

    @property
    def n_segments(self):
        return int(self.seg_start.shape[0])


class PrimitiveList(list):
    """The primitives of to_primitives; ``skipped`` counts degenerate ones left out."""
    skipped = 0


class _ModuleError(Exception):
    """Bad module input; apply_all re-raises it as a SceneError with the module index."""


def _orthonormal(hx, hy, hz, lx, ly, lz):
    """Gram-Schmidt on (H, L), then U = H x L: a right-handed frame again."""
    n = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * n, hy * n, hz * n
    d = lx * hx + ly * hy + lz * hz
    lx, ly, lz = lx - d * hx, ly - d * hy, lz - d * hz
    n = 1.0 / math.sqrt(lx * lx + ly * ly + lz * lz)
    lx, ly, lz = lx * n, ly * n, lz * n
    return ((hx, hy, hz), (lx, ly, lz),
            (hy * lz - hz * ly, hz * lx - hx * lz, hx * ly - hy * lx))


class TurtleState:
    """The turtle: one implementation of the conventions, applied module by module.

    ``apply(module)`` / ``apply_all(modules)`` advance it; ``matrix()`` is the
    current frame as a 4x4 affine (columns L, U, H, position), so a scene-graph
    builder can interpret substrings and read exit transforms. Everything drawn
    so far is collected; ``geometry()`` returns it as arrays.
    """

    def __init__(self, angle=90.0, width=0.1):
        self.angle = float(angle)
        if not -_INF < self.angle < _INF:
            raise SceneError(f"turtle: angle must be finite, got {angle!r}")
        a = math.radians(self.angle)
        self._c, self._s = math.cos(a), math.sin(a)
        self.default_width = float(width)
        if not 0.0 <= self.default_width < _INF:
            raise SceneError(f"turtle: width must be finite and >= 0, got {width!r}")
        self.p = (0.0, 0.0, 0.0)
        self.h = (0.0, 0.0, 1.0)
        self.l = (-1.0, 0.0, 0.0)
        self.u = (0.0, -1.0, 0.0)
        self.width = self.default_width
        self.drawn = None           # diameter of the previous segment on this branch
        self.material = 0
        self.count = 0              # modules applied so far (indexes error messages)
        self._stack = []
        self._seg = []              # rows of _ROW numbers
        self._frames = []           # L + U + H (9 floats) per distinct drawing frame
        self.fid = -1               # index of the current frame in _frames, -1: not recorded
        self._sph = []              # (x, y, z, r, material)
        self._box = []              # (x, y, z, L(3), U(3), H(3), side, material)
        self._organs = []
        self._handlers = {
            "F": self._draw, "f": self._move, "[": self._push, "]": self._pop,
            "+": self._left, "-": self._right, "&": self._down, "^": self._up,
            "\\": self._roll_left, "/": self._roll_right, "|": self._turn_around,
            "!": self._set_width, "@O": self._sphere, "@B": self._box_module,
            ";": self._set_material,
            "~": self._organ,
        }

    # ------------------------------------------------------------- reading

    @property
    def position(self):
        return np.array(self.p)

    @property
    def heading(self):
        return np.array(self.h)

    @property
    def left(self):
        return np.array(self.l)

    @property
    def up(self):
        return np.array(self.u)

    @property
    def depth(self):
        """Open ``[`` on the stack."""
        return len(self._stack)

    def matrix(self):
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = self.l, self.u, self.h, self.p
        return m

    # ------------------------------------------------------------- applying

    def apply(self, module):
        return self.apply_all((module,))

    def apply_all(self, modules):
        get = self._handlers.get
        i = self.count - 1
        try:
            for i, (sym, params) in enumerate(modules, self.count):
                h = get(sym)
                if h is not None:
                    h(params)
        except SceneError:
            raise
        except (_ModuleError, TypeError, ValueError, IndexError) as e:
            # TypeError/ValueError: a parameter that is not a number or a
            # module that is not a (symbol, params) pair.
            raise SceneError(f"L-system module {i}: {e}") from None
        self.count = i + 1
        return self

    # ------------------------------------------------------------- handlers
    # Each takes the module's params (a tuple or list, possibly empty) and raises
    # _ModuleError for values it cannot draw; apply_all adds the module index.

    def _draw(self, params):
        d = float(params[0]) if params else 1.0
        if not -_INF < d < _INF:
            raise _ModuleError(f"'F' length must be finite, got {d!r}")
        p, h = self.p, self.h
        q = (p[0] + d * h[0], p[1] + d * h[1], p[2] + d * h[2])
        w = self.width
        w0 = w if self.drawn is None else self.drawn
        fid = self.fid
        if fid < 0:
            fid = self.fid = len(self._frames)
            self._frames.append(self.l + self.u + h)
        self._seg.append(p + q + (w0, w, self.material, fid))
        self.p = q
        self.drawn = w

    def _move(self, params):
        d = float(params[0]) if params else 1.0
        if not -_INF < d < _INF:
            raise _ModuleError(f"'f' length must be finite, got {d!r}")
        p, h = self.p, self.h
        self.p = (p[0] + d * h[0], p[1] + d * h[1], p[2] + d * h[2])

    def _push(self, params):
        self._stack.append((self.p, self.h, self.l, self.u, self.width, self.drawn, self.material,
                            self.fid))

    def _pop(self, params):
        if not self._stack:
            raise _ModuleError("unmatched ']' (no '[' to pop)")
        (self.p, self.h, self.l, self.u, self.width, self.drawn, self.material,
         self.fid) = self._stack.pop()

    def _cs(self, params, sign):
        a = float(params[0])
        if not -_INF < a < _INF:
            raise _ModuleError(f"rotation angle must be finite, got {a!r}")
        a = math.radians(a)
        return math.cos(a), sign * math.sin(a)

    def _yaw(self, c, s):
        # About U: H' = H c + (U x H) s = H c + L s, L' = L c + (U x L) s = L c - H s.
        h, l = self.h, self.l
        self.fid = -1
        self.h, self.l, self.u = _orthonormal(
            h[0] * c + l[0] * s, h[1] * c + l[1] * s, h[2] * c + l[2] * s,
            l[0] * c - h[0] * s, l[1] * c - h[1] * s, l[2] * c - h[2] * s)

    def _pitch(self, c, s):
        # About L: H' = H c + (L x H) s = H c - U s (U' follows as H' x L).
        h, u, l = self.h, self.u, self.l
        self.fid = -1
        self.h, self.l, self.u = _orthonormal(
            h[0] * c - u[0] * s, h[1] * c - u[1] * s, h[2] * c - u[2] * s, l[0], l[1], l[2])

    def _roll(self, c, s):
        # About H: L' = L c + (H x L) s = L c + U s (U' follows as H x L').
        h, l, u = self.h, self.l, self.u
        self.fid = -1
        self.h, self.l, self.u = _orthonormal(
            h[0], h[1], h[2], l[0] * c + u[0] * s, l[1] * c + u[1] * s, l[2] * c + u[2] * s)

    def _left(self, params):
        if params:
            self._yaw(*self._cs(params, 1.0))
        else:
            self._yaw(self._c, self._s)

    def _right(self, params):
        if params:
            self._yaw(*self._cs(params, -1.0))
        else:
            self._yaw(self._c, -self._s)

    def _down(self, params):
        if params:
            self._pitch(*self._cs(params, 1.0))
        else:
            self._pitch(self._c, self._s)

    def _up(self, params):
        if params:
            self._pitch(*self._cs(params, -1.0))
        else:
            self._pitch(self._c, -self._s)

    def _roll_left(self, params):
        if params:
            self._roll(*self._cs(params, 1.0))
        else:
            self._roll(self._c, self._s)

    def _roll_right(self, params):
        if params:
            self._roll(*self._cs(params, -1.0))
        else:
            self._roll(self._c, -self._s)

    def _turn_around(self, params):
        # Exact (no trigonometry): 180 degrees about U negates H and L.
        h, l = self.h, self.l
        self.h, self.l = (-h[0], -h[1], -h[2]), (-l[0], -l[1], -l[2])
        self.fid = -1

    def _set_width(self, params):
        w = float(params[0]) if params else self.default_width
        if not 0.0 <= w < _INF:
            raise _ModuleError(f"'!' width must be finite and >= 0, got {w!r}")
        self.width = w

    def _sphere(self, params):
        r = float(params[0]) if params else 0.5 * self.width
        if not 0.0 <= r < _INF:
            raise _ModuleError(f"'@O' radius must be finite and >= 0, got {r!r}")
        self._sph.append(self.p + (r, self.material))

    def _box_module(self, params):
        s = float(params[0]) if params else self.width
        if not 0.0 <= s < _INF:
            raise _ModuleError(f"'@B' size must be finite and >= 0, got {s!r}")
        self._box.append(self.p + self.l + self.u + self.h + (s, self.material))

    def _set_material(self, params):
        if not params:
            self.material += 1
            return
        v = float(params[0])
        if not (v >= 0 and v == int(v)):
            raise _ModuleError(f"';' material slot must be an integer >= 0, got {params[0]!r}")
        self.material = int(v)

    def _organ(self, params):
        if not params or not isinstance(params[0], str):
            raise _ModuleError(f"'~' needs an organ name first, got {tuple(params)!r}")
        s = float(params[1]) if len(params) > 1 else 1.0
        if not (0.0 < s < _INF):
            raise _ModuleError(f"'~' scale must be finite and > 0, got {s!r}")
        m = self.matrix()
        m[:3, :3] *= s
        self._organs.append(Organ(params[0], m, self.material))

    # ------------------------------------------------------------- output

    def geometry(self):
        """Everything drawn so far, as arrays (bounds: origin and segment ends)."""
        seg = np.fromiter(chain.from_iterable(self._seg), np.float64,
                          _ROW * len(self._seg)).reshape(-1, _ROW)
        frames = np.array(self._frames, dtype=np.float64).reshape(-1, 3, 3)
        sph = np.array(self._sph, dtype=np.float64).reshape(-1, 5)
        box = np.array(self._box, dtype=np.float64).reshape(-1, 14)
        end = seg[:, 3:6]
        pts = np.vstack([np.zeros((1, 3)), end])
        return TurtleGeometry(
            seg_start=seg[:, 0:3].copy(), seg_end=end.copy(),
            # rows L, U, H -> columns L, U, H
            seg_frame=frames[seg[:, 9].astype(np.int64)].transpose(0, 2, 1).copy(),
            seg_width0=seg[:, 6].copy(), seg_width1=seg[:, 7].copy(),
            seg_material=seg[:, 8].astype(np.int64),
            spheres=Spheres(sph[:, 0:3].copy(), sph[:, 3].copy(), sph[:, 4].astype(np.int64)),
            # rows L, U, H -> columns L, U, H
            boxes=Boxes(box[:, 0:3].copy(), box[:, 3:12].reshape(-1, 3, 3).transpose(0, 2, 1).copy(),
                        box[:, 12].copy(), box[:, 13].astype(np.int64)),
            organs=list(self._organs),
            bounds=(pts.min(axis=0), pts.max(axis=0)))


def interpret(modules, angle=90.0, width=0.1):
    """Turtle geometry of a module string (default angle in degrees, default diameter)."""
    return TurtleState(angle, width).apply_all(modules).geometry()


def frame_after(modules, angle=90.0, width=0.1):
    """The turtle after the whole string: .position, .heading, .left, .up, .width, .matrix()."""
    return TurtleState(angle, width).apply_all(modules)


def _degenerate(m):
    """True where a (k, 3, 3) linear part is singular by scene._affine's own test."""
    if not len(m):
        return np.zeros(0, dtype=bool)
    det = np.linalg.det(m)
    scale = np.maximum(np.abs(m).reshape(len(m), 9).max(axis=1), 1e-300)
    return ~(np.abs(det) > 1e-12 * scale ** 3)


def to_primitives(geom, material_base=0, name="lsystem"):
    """Analytic primitives for a TurtleGeometry (organs are not primitives).

    Cylinder: local x -> L w/2, y -> U w/2, z -> (end - start)/2, origin at the
    midpoint. Tapering segment: "frustum" (base radius 1 at z = -1, top radius
    t = params[0] at z = +1) with the base at the wider end, t = narrow/wide.
    Local x is negated wherever local z points against H (a widening segment,
    or F with a negative length), so every transform stays right-handed.
    Box: columns L s/2, U s/2, H s/2 (the engine box is [-1, 1]^3), origin at
    the box's centre. Order: segments, then spheres, then boxes, each in string
    order. Segments, spheres and boxes whose transform would be singular (zero
    length, width, radius or size) are left out and counted in ``skipped``.
    """
    out = PrimitiveList()
    n = geom.n_segments
    w0, w1 = geom.seg_width0, geom.seg_width1
    L, U, H = geom.seg_frame[:, :, 0], geom.seg_frame[:, :, 1], geom.seg_frame[:, :, 2]
    half = 0.5 * (geom.seg_end - geom.seg_start)          # start -> end, half length
    taper = w0 != w1
    widen = w1 > w0
    r = 0.5 * np.maximum(w0, w1)                           # radius of the base (wider) end
    zc = np.where(widen[:, None], -half, half)             # base -> top, half length
    sx = np.where(np.einsum("ij,ij->i", H, zc) >= 0.0, 1.0, -1.0)
    lin = np.stack([L * (sx * r)[:, None], U * r[:, None], zc], axis=2)   # columns
    t = np.where(taper, np.minimum(w0, w1) / np.where(r > 0, 2 * r, 1.0), 1.0)
    bad = _degenerate(lin)
    mid = 0.5 * (geom.seg_start + geom.seg_end)
    mats = material_base + geom.seg_material
    for i in range(n):
        if bad[i]:
            out.skipped += 1
            continue
        m = np.empty((3, 4))
        m[:, :3] = lin[i]
        m[:, 3] = mid[i]
        if taper[i]:
            out.append(Primitive("frustum", m, int(mats[i]), (float(t[i]),), f"{name}.segment.{i}"))
        else:
            out.append(Primitive("cylinder", m, int(mats[i]), (), f"{name}.segment.{i}"))
    sp = geom.spheres
    for j in range(len(sp.radius)):
        rj = float(sp.radius[j])
        if not rj > 0.0 or _degenerate(np.eye(3)[None] * rj)[0]:
            out.skipped += 1
            continue
        m = np.zeros((3, 4))
        m[0, 0] = m[1, 1] = m[2, 2] = rj
        m[:, 3] = sp.center[j]
        out.append(Primitive("sphere", m, int(material_base + sp.material[j]), (), f"{name}.sphere.{j}"))
    bx = geom.boxes
    lin = bx.frame * (0.5 * bx.size)[:, None, None]
    bad = _degenerate(lin)
    for k in range(len(bx.size)):
        if bad[k]:
            out.skipped += 1
            continue
        m = np.empty((3, 4))
        m[:, :3] = lin[k]
        m[:, 3] = bx.center[k]
        out.append(Primitive("box", m, int(material_base + bx.material[k]), (), f"{name}.box.{k}"))
    return out
