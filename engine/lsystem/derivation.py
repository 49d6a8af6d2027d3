"""Deriving an L-system (engine/lsystem/grammar.py): parallel rewriting, step by step,
with every stochastic choice drawn from the module's path hash; the proof that
rewriting to a fixpoint stops; and the module counts of a derivation, memoised per
module and remaining steps, so grammars far too large to derive are still counted.

Omitted derivation length: rewrite until a step changes nothing. For a
context-free grammar `check_termination` first explores the module states
reachable from the axiom (all stochastic alternatives) and refuses a state that
reaches itself or a chain longer than MAX_FIXPOINT_STEPS; a context-sensitive
grammar is only stopped after that many steps. A derived string may not exceed
`cap` modules; each step's length is known before its string is built.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .grammar import (MASK, Grammar, LSystemError, LSystemGrowthError, LSystemRecursionError,
                      bracket_pairs, child_hash_array, draw_array, format_string, splitmix64)

DEFAULT_CAP = 10_000_000
MAX_FIXPOINT_STEPS = 1000
# States check_termination explores before it stops trying to prove termination
# (derive then still stops after MAX_FIXPOINT_STEPS).
TERMINATION_STATES = 100_000


# ---------------------------------------------------------------- derivation

@dataclass
class Derivation:
    modules: list
    hashes: np.ndarray              # uint64, one per module: its derivation-tree path
    lengths: list                   # string length after each step, axiom first
    steps: int                      # steps applied (the fixpoint's when the length was omitted)
    grammar: Grammar

    def __str__(self):
        return format_string(self.modules)


def _growth_error(grammar, step, n, cap):
    msg = f"{grammar.source_name}: step {step} would derive {n:,} modules (cap {cap:,}); "
    if grammar.is_context_free:
        msg += ("a context-free grammar renders through the DCSG without deriving the string "
                "(the cyclic scene graph counts and traces it lazily), or lower the derivation length")
    else:
        msg += "lower the derivation length"
    return LSystemGrowthError(msg)


def _step(grammar, cur, hashes, step, cap):
    """One parallel rewrite: (new string, new hashes), or None when no module was rewritten."""
    table, choose = grammar.table, grammar.choose
    u = draw_array(hashes).tolist() if grammar.weighted else None
    context = None if grammar.is_context_free else (bracket_pairs(cur), grammar.ignore)
    succ = []
    for i, m in enumerate(cur):
        if m.symbol not in table:
            succ.append(None)
        else:
            where = None if context is None else (cur, context[0], i, context[1])
            succ.append(choose(m, u[i] if u is not None else 0.0, where))
    rewritten = np.fromiter((r is not None for r in succ), bool, len(cur))
    if not rewritten.any():
        return None
    lens = np.fromiter((1 if r is None else len(r) for r in succ), np.int64, len(cur))
    total = int(lens.sum())
    if total > cap:                     # refused before the string is built
        raise _growth_error(grammar, step, total, cap)
    new = []
    for m, r in zip(cur, succ):
        if r is None:
            new.append(m)
        else:
            new.extend(r)
    parent = np.repeat(np.arange(len(cur)), lens)
    j = np.arange(total) - np.repeat(np.cumsum(lens) - lens, lens)
    newh = hashes[parent]
    mask = np.repeat(rewritten, lens)
    newh[mask] = child_hash_array(newh[mask], j[mask])
    return new, newh


def derive(grammar, steps=None, cap=DEFAULT_CAP):
    """Rewrite the axiom `steps` times (default: the grammar's derivation length; when
    that is omitted too, to a fixpoint, after check_termination)."""
    if steps is None:
        steps = grammar.derivation_length
    fixpoint = steps is None
    if fixpoint:
        check_termination(grammar)
    elif steps < 0:
        raise LSystemError(f"{grammar.source_name}: derivation length must be >= 0, got {steps}")
    cur = list(grammar.axiom)
    if len(cur) > cap:
        raise _growth_error(grammar, 0, len(cur), cap)
    hashes = child_hash_array(np.full(len(cur), splitmix64(grammar.seed & MASK), np.uint64), np.arange(len(cur)))
    lengths, done = [len(cur)], 0
    while fixpoint or done < steps:
        out = _step(grammar, cur, hashes, done + 1, cap)
        if out is None or (fixpoint and out[0] == cur):
            break                       # nothing changes from here on
        if fixpoint and done == MAX_FIXPOINT_STEPS:
            raise LSystemRecursionError(
                f"{grammar.source_name}: no fixpoint after {MAX_FIXPOINT_STEPS} steps (the string "
                f"still changes at {len(out[0]):,} modules); give a derivation length")
        cur, hashes = out
        done += 1
        lengths.append(len(cur))
    if not fixpoint:
        lengths.extend([len(cur)] * (steps - done))
        done = steps
    return Derivation(cur, hashes, lengths, done, grammar)


# ---------------------------------------------------------------- termination and counting

def _chain(modules, most=6):
    names = [str(m) for m in modules]
    if len(names) > most:
        names = names[:most - 2] + ["…", names[-1]]
    return " -> ".join(names)


def check_termination(grammar, limit=MAX_FIXPOINT_STEPS, budget=TERMINATION_STATES):
    """Steps a context-free grammar needs to stop changing (every stochastic alternative
    considered), found by a memoised depth-first walk over the module states (symbol,
    params) reachable from the axiom. None when it cannot tell: the grammar has context,
    or more than `budget` states are reachable. Raises LSystemRecursionError for a state
    that reaches itself (A -> B -> A, A -> A B) or needs more than `limit` steps."""
    if not grammar.is_context_free:
        return None

    def expand(m):
        cands = grammar.candidates(m, None)
        return bool(cands), iter([c for prod, vals, _ in cands for c in prod.successor_modules(vals, m)])

    def refuse(m, why):
        return LSystemRecursionError(f"{grammar.source_name}: symbol {m.symbol} {why}; give a "
                                     "derivation length or a condition that ends it")

    height = {}
    for root in grammar.axiom:
        if root in height:
            continue
        has, it = expand(root)
        path, onpath, iters, best = [root], {root: 0}, [it], [int(has)]
        while path:
            child = next(iters[-1], None)
            if child is None:           # all successors done: 1 + the deepest of them
                m, h = path.pop(), best.pop()
                iters.pop()
                del onpath[m]
                height[m] = h
                if best:
                    best[-1] = max(best[-1], h + 1)
            elif child in height:
                best[-1] = max(best[-1], height[child] + 1)
            elif child in onpath:
                cycle = path[onpath[child]:] + [child]
                raise refuse(child, f"rewrites forever ({_chain(cycle)})")
            elif len(path) > limit:
                raise refuse(path[0], f"needs more than {limit} steps to stop rewriting ({_chain(path)})")
            elif len(height) + len(path) >= budget:
                return None
            else:
                has, it = expand(child)
                onpath[child] = len(path)
                path.append(child)
                iters.append(it)
                best.append(int(has))
    steps = max((height[m] for m in grammar.axiom), default=0)
    if steps > limit:
        deepest = max(grammar.axiom, key=height.get)
        raise refuse(deepest, f"needs {steps} steps to stop rewriting (more than {limit})")
    return steps


class Counts(NamedTuple):
    length: int | float
    per_symbol: dict
    exact: bool                     # False: expected values of a stochastic grammar (floats)


def count(grammar, steps=None, cap=DEFAULT_CAP):
    """Module counts of the derived string. A context-free grammar is counted without
    deriving it, memoised on (module, steps left) in Python ints (exact for 10^30
    modules); where a stochastic choice is met the counts are expectations (floats,
    exact=False). A context-sensitive grammar is derived (within `cap`) and counted."""
    if steps is None:
        steps = grammar.derivation_length
    if steps is None and grammar.is_context_free:
        steps = check_termination(grammar)
    if not grammar.is_context_free or steps is None:
        d = derive(grammar, steps, cap)
        return Counts(len(d.modules), dict(Counter(m.symbol for m in d.modules)), True)
    if steps < 0:
        raise LSystemError(f"{grammar.source_name}: derivation length must be >= 0, got {steps}")
    alts = {}                          # module -> [(probability, ((child, multiplicity), ...))]

    def alternatives(m):
        if m not in alts:
            alts[m] = [(p, tuple(Counter(prod.successor_modules(vals, m)).items()))
                       for prod, vals, p in grammar.candidates(m, None)]
        return alts[m]

    memo, chose = {}, False
    todo = [(m, steps, False) for m in set(grammar.axiom)]
    while todo:                         # post-order without recursion (steps may be large)
        m, r, ready = todo.pop()
        if (m, r) in memo:
            continue
        a = alternatives(m) if r > 0 else ()
        if not a:
            memo[m, r] = {m.symbol: 1}
        elif not ready:
            todo.append((m, r, True))
            todo.extend((c, r - 1, False) for _, kids in a for c, _ in kids if (c, r - 1) not in memo)
        else:
            chose |= len(a) > 1
            total = {}
            for p, kids in a:
                for c, k in kids:
                    w = k * p if len(a) > 1 else k      # stays an int where nothing is chosen
                    for s, n in memo[c, r - 1].items():
                        total[s] = total.get(s, 0) + n * w
            memo[m, r] = total
    per = {}
    for m, k in Counter(grammar.axiom).items():
        for s, n in memo[m, steps].items():
            per[s] = per.get(s, 0) + n * k
    if chose:
        per = {s: float(n) for s, n in per.items()}
    return Counts(sum(per.values()) if per else (0.0 if chose else 0), per, not chose)
