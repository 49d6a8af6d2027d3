"""Parametric, stochastic, context-sensitive L-systems (cpfg / L-Py flavoured grammars).

A grammar text (a Blender Text datablock or a file) is parsed into a `Grammar`
and rewritten by `derive` into a string of modules that engine/lsystem/turtle.py turns
into geometry. A context-free grammar can instead be rendered through the
cyclic scene graph (DCSG) without ever deriving its string, so `Grammar.
alternatives`, `Grammar.rewrite` and `count` work per module, and the seeded
generator below is part of the format: the scene graph recomputes every
stochastic choice from a module's hash alone.

Grammar text (`#` comments to end of line, blank lines ignored)::

    Axiom: A(1) B
    derivation length: 8   # int >= 0; omitted: rewrite to a fixpoint (<= 1000 steps)
    angle: 22.5            # turtle turn in degrees (90)
    ignore: + - F          # symbols context matching skips
    seed: 7                # stochastic choices (0)
    width: 0.1             # initial segment diameter (0.1)
    ol stub: A levels 2 3  # may repeat; without `levels` a stub at every level
    production:
    A(x) : x < 6 --> A(x+1) B(x)
    b < a > c --> b
    F --> F[+F]F : 0.6
    F --> F[-F]F : 0.4
    endlsystem             # optional at the end; anything after it is ignored

Header keys are case-insensitive; an unknown key is a syntax error.

Modules. One non-blank character, or `@` plus one (`@O`), followed directly by
optional parameters `(expr, ...)`; `[` and `]` push and pop. `( ) , : #` are
not module characters. The organ `~` takes a literal name first: `~(leaf, 0.5)`
is `Module("~", ("leaf", 0.5))` (an identifier or a quoted string). Other
parameters are floats.

Productions: `[left <] pred [> right] [: condition] --> successor [: probability]`.
Predecessor and context modules carry formal parameter names, which conditions,
successor parameters and probabilities use. An empty successor erases the
module. Brackets cannot be rewritten, and a left context holds no brackets.
A pattern matches a module of the same symbol and number of parameters only:
`A(x)` does not match `A(1, 2)`, which is then left unchanged (cpfg semantics).

Expressions: numbers, formal names, `+ - * / % **`, unary `-`, comparisons
`< > <= >= == !=` (chainable), `and or not` (also `&& || !`), parentheses,
and sqrt abs floor ceil exp log min max, and sin cos tan taking degrees.
Truth values are 1.0 and 0.0. `^` is not power (it is a turtle symbol): use
`**`. Expressions are compiled to closures here, never by Python's eval.

Context (ABOP 1.8, L-Py), matched against the previous step's string. Left:
walk left skipping ignored symbols and whole branches `[...]` to the left, and
step out of the current branch through its `[`. Right: walk right skipping
ignored symbols and branches the pattern does not open with `[`; the end of a
branch `]` fails, unless the pattern's own `]` asks to skip to it.

Choosing. The candidates for a module are the productions of its symbol whose
predecessor, context and condition match, in file order. Where no production of
that symbol gives a probability the first candidate wins. Where they do (and
then all of them must) the candidates' probabilities p_i (which may be
expressions) are normalised to their sum; with u = draw(h) the first whose
running float64 sum of p_i / sum(p) exceeds u is chosen (the last on rounding).
If all p_i are 0 the module stays unchanged. `is_stochastic` means some symbol
has more than one production with a probability.

The generator (exactly this; MASK = 2**64 - 1)::

    splitmix64(x): x += 0x9E3779B97F4A7C15; z = x
                   z = (z ^ z >> 30) * 0xBF58476D1CE4E5B9
                   z = (z ^ z >> 27) * 0x94D049BB133111EB
                   return z ^ z >> 31                      (all mod 2**64)
    child_hash(h, j) = splitmix64(h ^ (j + 1) * 0x9E3779B97F4A7C15)
    axiom module i:    child_hash(splitmix64(seed & MASK), i)
    draw(h)          = (splitmix64(h ^ 0xD1B54A32D192ED03) >> 11) * 2**-53

Rewriting a module of hash h gives successor module j (every module counted,
brackets included) the hash child_hash(h, j); a module left unchanged keeps its
hash. A choice depends only on the module's path in the derivation tree.

Rewriting (`derive`), the termination proof (`check_termination`) and counting
without deriving (`count`) are engine/lsystem/derivation.py.
"""
from __future__ import annotations

import math
import operator
import os
import re
from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..core.scene import SceneError



class LSystemError(SceneError):
    """An L-system that cannot be parsed or derived (names the grammar)."""


class LSystemSyntaxError(LSystemError):
    def __init__(self, source, line, column, message):
        super().__init__(f"{source}: line {line}, column {column}: {message}")
        self.line, self.column = line, column


class LSystemGrowthError(LSystemError):
    """The derived string would exceed the module cap."""


class LSystemRecursionError(LSystemError):
    """Rewriting to a fixpoint would never stop."""


# ---------------------------------------------------------------- generator

MASK = 2 ** 64 - 1
_GOLDEN = 0x9E3779B97F4A7C15
_DRAW_SALT = 0xD1B54A32D192ED03


def splitmix64(x):
    x = (x + _GOLDEN) & MASK
    z = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def child_hash(h, j):
    """Hash of module j (0-based) of the successor that replaced a module of hash h."""
    return splitmix64(h ^ (((j + 1) * _GOLDEN) & MASK))


def root_hash(seed, i):
    """Hash of axiom module i."""
    return child_hash(splitmix64(seed & MASK), i)


def draw(h):
    """Uniform in [0, 1) for the stochastic choice of a module of hash h."""
    return (splitmix64(h ^ _DRAW_SALT) >> 11) * 2.0 ** -53


def _splitmix64_array(x):
    with np.errstate(over="ignore"):        # uint64 arithmetic wraps, as intended
        x = x + np.uint64(_GOLDEN)
        z = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def child_hash_array(h, j):
    """child_hash over uint64 arrays (numpy < 2 turns uint64 mixed with Python ints into floats)."""
    j = np.asarray(j).astype(np.uint64)
    with np.errstate(over="ignore"):
        return _splitmix64_array(np.asarray(h, np.uint64) ^ ((j + np.uint64(1)) * np.uint64(_GOLDEN)))


def draw_array(h):
    z = _splitmix64_array(np.asarray(h, np.uint64) ^ np.uint64(_DRAW_SALT))
    return (z >> np.uint64(11)).astype(np.float64) * 2.0 ** -53


# ---------------------------------------------------------------- modules

class Module(NamedTuple):
    symbol: str
    params: tuple = ()

    def __str__(self):
        if not self.params:
            return self.symbol
        return f"{self.symbol}({', '.join(map(_param_text, self.params))})"


def _param_text(p):
    return p if isinstance(p, str) else f"{p:g}" if float(f"{p:g}") == p else repr(p)


class OLStub(NamedTuple):
    symbol: str
    levels: tuple | None = None     # derivation steps at which the symbol is a stub; None: all


def format_string(modules):
    """'F[+F]A(1)' for a module sequence (parses back to the same modules)."""
    return "".join(map(str, modules))


# ---------------------------------------------------------------- tokens and expressions

_TOKEN = re.compile(r"""(?P<ws>\s+)
    |(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
    |(?P<name>[A-Za-z_]\w*)
    |(?P<str>"[^"]*"|'[^']*')
    |(?P<op>\*\*|<=|>=|==|!=|&&|\|\||[-+*/%<>!(),])""", re.X)
_KEYWORDS = {"and", "or", "not"}


class _Tok(NamedTuple):
    kind: str
    text: str
    col: int                        # 0-based in the line


class _Src:
    """One line of grammar text, for errors that point into it."""

    def __init__(self, name, lineno, text):
        self.name, self.lineno, self.text = name, lineno, text

    def error(self, col, message):
        return LSystemSyntaxError(self.name, self.lineno, col + 1, message)


def _tokens(src, start, end):
    out, i, s = [], start, src.text
    while i < end:
        m = _TOKEN.match(s, i, end)
        if not m:
            hint = " ('^' is a turtle symbol, not power: use '**')" if s[i] == "^" else ""
            raise src.error(i, f"unexpected {s[i]!r} in an expression{hint}")
        if m.lastgroup != "ws":
            out.append(_Tok(m.lastgroup, m.group(), i))
        i = m.end()
    return out


class _E:
    """A compiled expression: fn(values) -> float; constants are folded at parse time."""
    __slots__ = ("fn", "value", "const")

    def __init__(self, fn=None, value=None):
        self.const, self.value = fn is None, value
        self.fn = fn if fn is not None else (lambda v, c=value: c)


def _truth(op):
    return lambda a, b: 1.0 if op(a, b) else 0.0


_ARITH = {"+": operator.add, "-": operator.sub, "*": operator.mul, "/": operator.truediv,
          "%": operator.mod, "**": math.pow}
_CMP = {k: _truth(o) for k, o in (("<", operator.lt), (">", operator.gt), ("<=", operator.le),
                                  (">=", operator.ge), ("==", operator.eq), ("!=", operator.ne))}
_LOGIC = (("or", "||"), ("and", "&&"))
_ARITH_LEVELS = (("+", "-"), ("*", "/", "%"))
_FUNCS = {  # name: (min args, max args or None, function)
    "sqrt": (1, 1, math.sqrt), "abs": (1, 1, abs), "exp": (1, 1, math.exp), "log": (1, 1, math.log),
    "floor": (1, 1, lambda x: float(math.floor(x))), "ceil": (1, 1, lambda x: float(math.ceil(x))),
    "sin": (1, 1, lambda d: math.sin(math.radians(d))), "cos": (1, 1, lambda d: math.cos(math.radians(d))),
    "tan": (1, 1, lambda d: math.tan(math.radians(d))), "min": (1, None, min), "max": (1, None, max),
}


def _fold(src, col, f, args):
    """f over compiled args: evaluated now when all are constant (errors point at col)."""
    if all(a.const for a in args):
        try:
            return _E(value=float(f(*[a.value for a in args])))
        except (ArithmeticError, ValueError) as e:
            raise src.error(col, f"{e} in a constant expression") from None
    fns = [a.fn for a in args]
    if len(fns) == 1:
        (a,) = fns
        return _E(lambda v: f(a(v)))
    if len(fns) == 2:
        a, b = fns
        return _E(lambda v: f(a(v), b(v)))
    return _E(lambda v: f(*[g(v) for g in fns]))


def _logic(a, b, is_or):
    if a.const and b.const:
        return _E(value=float(bool(a.value or b.value) if is_or else bool(a.value and b.value)))
    af, bf = a.fn, b.fn
    if is_or:
        return _E(lambda v: 1.0 if (af(v) or bf(v)) else 0.0)
    return _E(lambda v: 1.0 if (af(v) and bf(v)) else 0.0)


class _Parser:
    """Recursive descent over one expression's tokens; `names` maps formal names to value slots."""

    def __init__(self, src, toks, names, end_col):
        self.src, self.toks, self.names, self.end_col, self.i = src, toks, names, end_col, 0

    def peek(self):
        return self.toks[self.i] if self.i < len(self.toks) else None

    def at(self, *texts):
        t = self.peek()
        return t is not None and t.kind in ("op", "name") and t.text in texts

    def take(self):
        self.i += 1
        return self.toks[self.i - 1]

    def fail(self, message):
        t = self.peek()
        found = f", found {t.text!r}" if t else ", found the end of the expression"
        return self.src.error(t.col if t else self.end_col, message + found)

    def expect(self, text):
        if not self.at(text):
            raise self.fail(f"expected {text!r}")
        self.take()

    def parse(self):
        e = self.logic()
        if self.peek() is not None:
            raise self.fail("expected an operator or the end of the expression")
        return e

    def logic(self, level=0):           # or, then and, then not
        if level == 2:
            if self.at("not", "!"):
                col = self.take().col
                return _fold(self.src, col, lambda x: 0.0 if x else 1.0, [self.logic(2)])
            return self.cmp()
        e = self.logic(level + 1)
        while self.at(*_LOGIC[level]):
            self.take()
            e = _logic(e, self.logic(level + 1), level == 0)
        return e

    def cmp(self):
        left, result = self.arith(), None
        while self.at(*_CMP):           # a < b < c is (a < b) and (b < c)
            op = self.take()
            right = self.arith()
            c = _fold(self.src, op.col, _CMP[op.text], [left, right])
            result = c if result is None else _logic(result, c, False)
            left = right
        return left if result is None else result

    def arith(self, level=0):           # + -, then * / %
        if level == 2:
            return self.unary()
        e = self.arith(level + 1)
        while self.at(*_ARITH_LEVELS[level]):
            op = self.take()
            e = _fold(self.src, op.col, _ARITH[op.text], [e, self.arith(level + 1)])
        return e

    def unary(self):
        if self.at("-", "+"):
            op = self.take()
            e = self.unary()
            return e if op.text == "+" else _fold(self.src, op.col, operator.neg, [e])
        e = self.atom()
        if self.at("**"):               # right-associative, binds tighter than unary minus
            op = self.take()
            e = _fold(self.src, op.col, math.pow, [e, self.unary()])
        return e

    def atom(self):
        t = self.peek()
        if t is None:
            raise self.fail("expected a value")
        if t.kind == "num":
            self.take()
            return _E(value=float(t.text))
        if t.text == "(":
            self.take()
            e = self.logic()
            self.expect(")")
            return e
        if t.kind == "name" and t.text not in _KEYWORDS:
            self.take()
            return self.call(t) if self.at("(") else self.name(t)
        if t.kind == "str":
            raise self.src.error(t.col, "a quoted string is only allowed as an organ name: ~(\"name\", ...)")
        raise self.fail("expected a value")

    def name(self, t):
        slot = self.names.get(t.text)
        if slot is None:
            bound = f" (this production binds {', '.join(self.names)})" if self.names else ""
            raise self.src.error(t.col, f"undefined parameter {t.text!r}{bound}")
        return _E(lambda v: v[slot])

    def call(self, t):
        spec = _FUNCS.get(t.text)
        if spec is None:
            raise self.src.error(t.col, f"unknown function {t.text!r} (known: {', '.join(sorted(_FUNCS))})")
        self.take()
        args = [] if self.at(")") else [self.logic()]
        while args and self.at(","):
            self.take()
            args.append(self.logic())
        self.expect(")")
        lo, hi, f = spec
        if len(args) < lo or (hi is not None and len(args) > hi):
            want = lo if hi == lo else f"at least {lo}"
            raise self.src.error(t.col, f"{t.text}() takes {want} argument(s), got {len(args)}")
        return _fold(self.src, t.col, f, args)


# ---------------------------------------------------------------- module strings

def _outside(s, start, end):
    """(index, char, paren depth) for characters outside quoted organ names. Quotes only
    open a name within parentheses (elsewhere ' and " are module symbols)."""
    depth, quote = 0, None
    for i in range(start, end):
        c = s[i]
        if quote:
            quote = None if c == quote else quote
            continue
        if depth and c in "'\"":
            quote = c
            continue
        if c == ")":
            depth -= 1
        yield i, c, depth
        if c == "(":
            depth += 1


def _strip_comment(s):
    return next((s[:i] for i, c, _ in _outside(s, 0, len(s)) if c == "#"), s)


def _check_parens(src, start, end):
    opens = []
    for i, c, _ in _outside(src.text, start, end):
        if c == "(":
            opens.append(i)
        elif c == ")":
            if not opens:
                raise src.error(i, "unmatched ')'")
            opens.pop()
    if opens:
        raise src.error(opens[-1], "'(' is never closed: expected ')'")


class Pattern(NamedTuple):
    """A predecessor or context module: symbol, formal parameter names, organ name (or None)."""
    symbol: str
    names: tuple = ()
    organ: str | None = None

    def bind(self, m):
        """The values m gives the formal names, or None if m does not fit (symbol, arity, organ)."""
        if m.symbol != self.symbol:
            return None
        p = m.params
        if self.organ is None:
            return p if len(p) == len(self.names) else None
        return p[1:] if len(p) == len(self.names) + 1 and p[0] == self.organ else None


def _param_groups(src, toks, close):
    """Split parameter tokens at top-level commas: [(tokens, column the group ends at)]."""
    if not toks:
        return []
    groups, cur, depth = [], [], 0
    for t in toks:
        if t.text == "," and depth == 0 and t.kind == "op":
            groups.append((cur, t.col))
            cur = []
            continue
        depth += (t.text == "(") - (t.text == ")")
        cur.append(t)
    groups.append((cur, close))
    for g, end in groups:
        if not g:
            raise src.error(end, "expected a parameter")
    return groups


def _parse_modules(src, start, end, names):
    """The modules of src.text[start:end]. names None: patterns, items (Pattern, col,
    [(name, col)]); otherwise items (symbol, organ, [_E], col) with parameters that are
    expressions over `names` (a dict of formal name -> value slot)."""
    _check_parens(src, start, end)
    s, i, out = src.text, start, []
    while i < end:
        c = s[i]
        if c.isspace():
            i += 1
            continue
        if c in "(),:":
            why = " (parameters follow their module directly)" if c == "(" else ""
            raise src.error(i, f"unexpected {c!r}{why}")
        col = i
        if c == "@":
            if i + 1 >= end or s[i + 1].isspace() or s[i + 1] in "(),:":
                raise src.error(i, "'@' must be followed by a symbol character (as in @O)")
            c = s[i:i + 2]
        i += len(c)
        groups = []
        if i < end and s[i] == "(":
            close = next(j for j, ch, d in _outside(s, i, end) if ch == ")" and d == 0)
            groups = _param_groups(src, _tokens(src, i + 1, close), close)
            if groups and c in "[]":
                raise src.error(i, "brackets take no parameters")
            i = close + 1
        organ = None
        if c == "~" and groups:
            first, _ = groups.pop(0)
            if len(first) != 1 or first[0].kind not in ("name", "str"):
                raise src.error(first[0].col, "an organ's first parameter is its name: ~(leaf, ...) or ~(\"leaf\", ...)")
            organ = first[0].text[1:-1] if first[0].kind == "str" else first[0].text
        if names is None:
            formals = []
            for g, _ in groups:
                if len(g) != 1 or g[0].kind != "name" or g[0].text in _KEYWORDS:
                    raise src.error(g[0].col, "a predecessor or context parameter must be a name")
                formals.append((g[0].text, g[0].col))
            out.append((Pattern(c, tuple(n for n, _ in formals), organ), col, formals))
        else:
            out.append((c, organ, [_Parser(src, g, names, e).parse() for g, e in groups], col))
    return out


def _constant_modules(items):
    return tuple(Module(sym, ((organ,) if organ is not None else ()) + tuple(float(e.value) for e in exprs))
                 for sym, organ, exprs, _ in items)


# ---------------------------------------------------------------- productions

class Production:
    """One compiled rule `left < pred > right : condition --> successor : probability`."""

    def __init__(self, left, pred, right, condition, successor, probability, line, text, source):
        self.left, self.pred, self.right = tuple(left), pred, tuple(right)
        self.condition, self.probability = condition, probability
        self.line, self.text, self.source = line, text, source
        # (symbol, organ prefix, parameter functions, prebuilt module where all are constant)
        self._succ = [(sym, (organ,) if organ is not None else (), [e.fn for e in exprs],
                       Module(sym, ((organ,) if organ is not None else ()) + tuple(float(e.value) for e in exprs))
                       if all(e.const for e in exprs) else None)
                      for sym, organ, exprs, _ in successor]
        self._const = tuple(m for *_, m in self._succ) if all(t[3] is not None for t in self._succ) else None

    def __repr__(self):
        return f"<Production line {self.line}: {self.text}>"

    def apply(self, module, left=(), right=()):
        """Successor modules for `module` (with the context modules it matched, in pattern
        order). The condition is not checked here: alternatives() and derive() do that."""
        pats, mods = self.left + (self.pred,) + self.right, tuple(left) + (module,) + tuple(right)
        vals = [p.bind(m) for p, m in zip(pats, mods)] if len(pats) == len(mods) else [None]
        if any(v is None for v in vals):
            raise LSystemError(f"{self.source}: line {self.line}: {module} does not fit {self.text!r}")
        return list(self.successor_modules(sum(vals, ()), module))

    def _error(self, module, e):
        return LSystemError(f"{self.source}: line {self.line}: {e} while rewriting {module}")

    def _match(self, module, where):
        """Formal parameter values if this production applies to module, else None. where:
        (string, bracket pairs, index, ignore) of the module for context, or None."""
        vals = self.pred.bind(module)
        if vals is None:
            return None
        if self.left or self.right:
            cur, pairs, i, ignore = where
            lv = _left_context(cur, pairs, i, self.left, ignore) if self.left else ()
            if lv is None:
                return None
            rv = _right_context(cur, pairs, i, self.right, ignore) if self.right else ()
            if rv is None:
                return None
            vals = lv + vals + rv
        if self.condition is not None:
            try:
                if not self.condition.fn(vals):
                    return None
            except (ArithmeticError, ValueError) as e:
                raise self._error(module, e) from None
        return vals

    def _weight(self, vals, module):
        try:
            p = self.probability.fn(vals)
        except (ArithmeticError, ValueError) as e:
            raise self._error(module, e) from None
        if not (p >= 0 and math.isfinite(p)):
            raise self._error(module, f"probability {p} is not a finite number >= 0")
        return p

    def successor_modules(self, vals, module):
        if self._const is not None:
            return self._const
        try:
            return [m if m is not None else Module(sym, head + tuple([float(f(vals)) for f in fns]))
                    for sym, head, fns, m in self._succ]
        except (ArithmeticError, ValueError) as e:
            raise self._error(module, e) from None


def _left_context(cur, pairs, i, pats, ignore):
    vals, k, j = [], len(pats) - 1, i - 1
    while k >= 0:
        if j < 0:
            return None
        m = cur[j]
        if m.symbol == "]":             # a whole branch to the left: skip it
            if pairs[j] < 0:
                return None
            j = pairs[j] - 1
            continue
        if m.symbol == "[" or m.symbol in ignore:   # "[": step out into the parent branch
            j -= 1
            continue
        v = pats[k].bind(m)
        if v is None:
            return None
        vals.append(v)
        k, j = k - 1, j - 1
    return sum(reversed(vals), ())


def _right_context(cur, pairs, i, pats, ignore):
    vals, k, j, n = [], 0, i + 1, len(cur)
    while k < len(pats):
        if j >= n:
            return None
        m, want = cur[j], pats[k].symbol
        if m.symbol in ignore:
            j += 1
        elif want == "]":               # skip the rest of this branch up to its end
            while j < n and cur[j].symbol != "]":
                if cur[j].symbol == "[":
                    if pairs[j] < 0:
                        return None
                    j = pairs[j]
                j += 1
            if j >= n:
                return None
            k, j = k + 1, j + 1
        elif m.symbol == "[" and want != "[":
            if pairs[j] < 0:
                return None
            j = pairs[j] + 1
        else:                           # includes "]" against anything but "]": fails
            v = pats[k].bind(m)
            if v is None:
                return None
            vals.append(v)
            k, j = k + 1, j + 1
    return sum(vals, ())


def bracket_pairs(cur):
    pairs, stack = [-1] * len(cur), []
    for i, m in enumerate(cur):
        if m.symbol == "[":
            stack.append(i)
        elif m.symbol == "]" and stack:
            j = stack.pop()
            pairs[i], pairs[j] = j, i
    return pairs


def _production(src):
    s, n = src.text, len(src.text)
    _check_parens(src, 0, n)
    top = [(i, c) for i, c, d in _outside(s, 0, n) if d == 0]
    arrow = next((i for i, c in top if c == "-" and s.startswith("-->", i)), -1)
    if arrow < 0:
        raise src.error(len(s.rstrip()), "expected '-->' between predecessor and successor")
    colon = next((i for i, c in top if i < arrow and c == ":"), -1)
    head_end = arrow if colon < 0 else colon
    lts = [i for i, c in top if i < head_end and c == "<"]
    gts = [i for i, c in top if i < head_end and c == ">"]
    for marks, what in ((lts, "'<' (left context)"), (gts, "'>' (right context)")):
        if len(marks) > 1:
            raise src.error(marks[1], f"a production has at most one {what}")
    lt = lts[0] if lts else -1
    gt = gts[0] if gts else head_end
    if lts and gts and gt < lt:
        raise src.error(gt, "the right context '>' must follow the left context '<'")
    left = _parse_modules(src, 0, lt, None) if lts else []
    pred = _parse_modules(src, lt + 1, gt, None)
    right = _parse_modules(src, gt + 1, head_end, None) if gts else []
    if lts and not left:
        raise src.error(lt, "expected left context modules before '<'")
    if gts and not right:
        raise src.error(gt, "expected right context modules after '>'")
    if not pred:
        raise src.error(gt, "expected a predecessor module")
    if len(pred) > 1:
        raise src.error(pred[1][1], "one predecessor module only (context goes before '<' or after '>')")
    if pred[0][0].symbol in "[]":
        raise src.error(pred[0][1], "brackets cannot be rewritten")
    for pat, col, _ in left:
        if pat.symbol in "[]":
            raise src.error(col, "a left context holds no brackets (branches to the left are skipped)")
    slots = {}
    for _, _, formals in left + pred + right:     # value order: left, predecessor, right
        for name, col in formals:
            if name in slots:
                raise src.error(col, f"parameter {name!r} is bound twice")
            slots[name] = len(slots)
    condition = _expression(src, colon, arrow, slots, "a condition")[0] if colon >= 0 else None
    pcolon = next((i for i, c in top if i > arrow + 2 and c == ":"), -1)
    successor = _parse_modules(src, arrow + 3, n if pcolon < 0 else pcolon, slots)
    probability, pcol = _expression(src, pcolon, n, slots, "a probability") if pcolon >= 0 else (None, arrow)
    if probability is not None and probability.const and not (
            probability.value >= 0 and math.isfinite(probability.value)):
        raise src.error(pcol, "a probability must be a finite number >= 0")
    prod = Production([p for p, _, _ in left], pred[0][0], [p for p, _, _ in right], condition,
                      successor, probability, src.lineno, s.strip(), src.name)
    return prod, pcol               # where a probability mix-up is reported


def _expression(src, colon, end, slots, what):
    toks = _tokens(src, colon + 1, end)
    if not toks:
        raise src.error(colon, f"expected {what} after ':'")
    return _Parser(src, toks, slots, end).parse(), toks[0].col


# ---------------------------------------------------------------- grammar

@dataclass
class Grammar:
    axiom: tuple
    productions: tuple = ()
    derivation_length: int | None = None
    angle: float = 90.0
    ignore: frozenset = frozenset()
    seed: int = 0
    width: float = 0.1
    ol_stubs: tuple = ()
    source_name: str = "<grammar>"
    table: dict = field(init=False, repr=False)
    weighted: frozenset = field(init=False, repr=False)

    def __post_init__(self):
        self.table = {}
        for p in self.productions:
            self.table.setdefault(p.pred.symbol, []).append(p)
        self.weighted = frozenset(p.pred.symbol for p in self.productions if p.probability is not None)

    @property
    def is_context_free(self):
        return not any(p.left or p.right for p in self.productions)

    @property
    def is_stochastic(self):
        n = Counter(p.pred.symbol for p in self.productions if p.probability is not None)
        return any(k > 1 for k in n.values())

    def alternatives(self, module):
        """[(Production, normalised probability)] that may rewrite `module` (context-free
        grammars; conditions evaluated). Deterministic: the first match with 1.0. Empty:
        the module stays unchanged."""
        self._require_context_free("alternatives")
        return [(prod, p) for prod, _, p in self.candidates(module, None)]

    def rewrite(self, module, h):
        """The successor chosen for `module` with hash h (list of Modules), or None when no
        production matches. The same choice derive() makes (context-free grammars)."""
        self._require_context_free("rewrite")
        out = self.choose(module, draw(h) if module.symbol in self.weighted else 0.0, None)
        return None if out is None else list(out)

    def _require_context_free(self, what):
        if not self.is_context_free:
            raise LSystemError(f"{self.source_name}: {what}() needs a context-free grammar; "
                               "this one has context: derive() it")

    def candidates(self, module, where):
        """[(production, values, normalised probability)] by the rules of the module docstring."""
        prods = self.table.get(module.symbol, ())
        if module.symbol not in self.weighted:
            for prod in prods:
                vals = prod._match(module, where)
                if vals is not None:
                    return [(prod, vals, 1.0)]
            return []
        cands = []
        for prod in prods:
            vals = prod._match(module, where)
            if vals is not None:
                p = prod._weight(vals, module)
                if p > 0:
                    cands.append((prod, vals, p))
        total = sum(p for _, _, p in cands)
        return [(prod, vals, p / total) for prod, vals, p in cands]

    def choose(self, module, u, where):
        cands = self.candidates(module, where) if module.symbol in self.table else None
        if not cands:
            return None
        cum = 0.0
        for prod, vals, p in cands:     # deterministic: one candidate, p = 1 > u = 0
            cum += p
            if cum > u:
                break                   # else (rounding) the last one
        return prod.successor_modules(vals, module)


_HEADER_KEYS = ("axiom", "derivation length", "angle", "ignore", "seed", "width", "ol stub")


def _number(src, col, value, what, kind=float, minimum=None):
    try:
        x = kind(value)
    except ValueError:
        x = None
    if x is None or not math.isfinite(x) or (minimum is not None and x < minimum):
        need = "a whole number" if kind is int else "a number"
        raise src.error(col, f"{what} must be {need}" + (f" >= {minimum}" if minimum is not None else "")
                        + f", got {value!r}")
    return x


def _ol_stub(src, col, value):
    words = [(m.group(), col + m.start()) for m in re.finditer(r"\S+", value)]
    sym, scol = words[0]
    if len(sym) != 1 and not (len(sym) == 2 and sym[0] == "@") or sym in "()[],:":
        raise src.error(scol, f"ol stub: expected one module symbol, got {sym!r}")
    if len(words) == 1:
        return OLStub(sym, None)
    if words[1][0].lower() != "levels" or len(words) == 2:
        raise src.error(words[1][1], "ol stub: expected 'levels' and one or more derivation steps")
    return OLStub(sym, tuple(_number(src, c, w, "a level", int, 0) for w, c in words[2:]))


def parse(text, name="<grammar>"):
    """Grammar from its text; `name` (a file or Text datablock name) leads every error."""
    head, stubs, prods, mode = {}, [], [], {}
    in_prods, prod_line = False, None
    for lineno, raw in enumerate(text.splitlines(), 1):
        s = _strip_comment(raw)
        if not s.strip():
            continue
        if s.strip().lower() == "endlsystem":
            break
        src = _Src(name, lineno, s)
        if in_prods:
            prod, col = _production(src)
            sym, has = prod.pred.symbol, prod.probability is not None
            if sym in mode and mode[sym][0] != has:
                raise src.error(col, f"productions for {sym} on lines {mode[sym][1]} and {lineno} mix "
                                     "alternatives with and without a probability")
            mode.setdefault(sym, (has, lineno))
            prods.append(prod)
            continue
        lead = len(s) - len(s.lstrip())
        colon = s.find(":")
        if colon < 0:
            raise src.error(lead, "expected 'key: value' (or 'production:' before the productions)")
        key = " ".join(s[:colon].lower().split())
        vcol = colon + 1 + len(s[colon + 1:]) - len(s[colon + 1:].lstrip())
        value = s[vcol:].rstrip()
        if key in ("production", "productions"):
            if value:
                raise src.error(vcol, "nothing may follow 'production:' on its line")
            in_prods, prod_line = True, lineno
            continue
        if key not in _HEADER_KEYS:
            raise src.error(lead, f"unknown header {key!r} (known: {', '.join(_HEADER_KEYS)}, production)")
        if key in head and key != "ol stub":
            raise src.error(lead, f"{key!r} is given twice (first on line {head[key][1]})")
        if not value:
            raise src.error(vcol, f"{key!r} needs a value")
        if key == "axiom":
            v = _constant_modules(_parse_modules(src, vcol, len(s), {}))
        elif key == "ignore":
            items = _parse_modules(src, vcol, len(s), {})
            for sym, organ, exprs, col in items:
                if exprs or organ is not None or sym in "[]":
                    raise src.error(col, "ignore: list symbols only (no parameters, no brackets)")
            v = frozenset(sym for sym, *_ in items)
        elif key == "derivation length":
            v = _number(src, vcol, value, key, int, 0)
        elif key == "seed":
            v = _number(src, vcol, value, key, int)
        elif key == "angle":
            v = _number(src, vcol, value, key)
        elif key == "width":
            v = _number(src, vcol, value, key)
            if v <= 0:
                raise src.error(vcol, f"width must be > 0, got {value!r}")
        else:
            stubs.append(_ol_stub(src, vcol, value))
            continue
        head[key] = (v, lineno)
    if "axiom" not in head:
        raise LSystemSyntaxError(name, prod_line or 1, 1, "missing 'axiom:' (the start string)")
    get = lambda k, d: head[k][0] if k in head else d  # noqa: E731
    return Grammar(axiom=head["axiom"][0], productions=tuple(prods),
                   derivation_length=get("derivation length", None), angle=get("angle", 90.0),
                   ignore=get("ignore", frozenset()), seed=get("seed", 0), width=get("width", 0.1),
                   ol_stubs=tuple(stubs), source_name=name)


def load(path):
    """Grammar from a file; errors name the file."""
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise LSystemError(f"{path}: cannot read the grammar ({e.strerror or e})") from None
    return parse(text, name=os.path.basename(path))
