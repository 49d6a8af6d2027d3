"""L-system grammars (engine/lsystem/grammar.py): ABOP examples, context, parameters, the seeded
generator, lazy counting, and errors that point at the culprit."""
import math
import time
from collections import Counter

import numpy as np
import pytest

from photon_lightmaps.engine.lsystem import grammar as L
from photon_lightmaps.engine.lsystem import derivation
from photon_lightmaps.engine.lsystem.grammar import Module
from photon_lightmaps.engine.core.scene import SceneError


def grammar(axiom, *productions, n=None, **head):
    lines = [f"axiom: {axiom}"] + ([f"derivation length: {n}"] if n is not None else [])
    lines += [f"{k.replace('_', ' ')}: {v}" for k, v in head.items()] + ["production:", *productions]
    return L.parse("\n".join(lines), name="test.lsys")


def text(d):
    return L.format_string(d.modules)


def symbols(d):
    return Counter(m.symbol for m in d.modules)


# ---------------------------------------------------------------- ABOP examples

def test_abop_1_24a_counts():
    # 1.24a: each F becomes 5 F plus 6 other modules ([ + ] [ - ]), so after n steps
    # F = 5^n and the others 6 (5^n - 1) / 4: n = 5 gives 3125 + 4686 = 7811 modules
    # (every bracket and turn is a module; no other convention needed).
    g = grammar("F", "F --> F[+F]F[-F]F", n=5, angle=25.7)
    d = derivation.derive(g)
    assert len(d.modules) == 7811 and symbols(d)["F"] == 3125
    assert d.lengths == [1, 11, 61, 311, 1561, 7811]
    assert g.angle == 25.7
    c = derivation.count(g)
    assert c.exact and c.length == 7811 and c.per_symbol == dict(symbols(d))


def test_koch_snowflake():
    g = grammar("F++F++F", "F --> F-F++F-F", n=4, angle=60)
    assert symbols(derivation.derive(g))["F"] == 768
    assert derivation.count(g).per_symbol["F"] == 768


def fib(n):
    a, b = 1, 1
    for _ in range(n):
        a, b = b, a + b
    return a


def test_algae_lengths_are_fibonacci():
    g = grammar("A", "A --> AB", "B --> A", n=15)
    d = derivation.derive(g)
    assert d.lengths == [fib(n + 1) for n in range(16)]
    assert text(derivation.derive(g, 4)) == "ABAABABA"


def test_count_matches_derive_and_scales():
    for g in (grammar("A", "A --> AB", "B --> A", n=12),
              grammar("F-F-F-F", "F --> FF-F-F-F-F-F+F", n=3),
              grammar("X", "X --> F[+X][-X]FX", "F --> FF", n=5),
              grammar("A(0)", "A(x) : x < 3 --> A(x+1) [B(x)] A(x+2)", "B(y) --> C", n=6)):
        d = derivation.derive(g)
        c = derivation.count(g)
        assert c.exact and c.length == len(d.modules) and c.per_symbol == dict(symbols(d))
    g = grammar("A", "A --> AB", "B --> A", n=200)
    t = time.perf_counter()
    c = derivation.count(g)
    assert time.perf_counter() - t < 1.0
    assert c.length == fib(201) and isinstance(c.length, int) and c.length > 10 ** 41
    assert c.per_symbol == {"A": fib(200), "B": fib(199)}


# ---------------------------------------------------------------- context

def test_signal_propagation():
    g = grammar("baaaaaaaa", "b < a --> b", "b --> a")
    assert not g.is_context_free
    for n in range(9):
        assert text(derivation.derive(g, n)) == "a" * n + "b" + "a" * (8 - n)
    d = derivation.derive(g)                     # fixpoint: the b has left
    assert text(d) == "a" * 9 and d.steps == 9


def test_left_context_skips_branches_and_leaves_them():
    g = grammar("B[C]A[A]C[A]", "B < A --> X", "C < A --> Y")
    # first A: the branch [C] to its left is skipped, B is its context; second A sits in a
    # branch whose parent is that A; third A steps out of its branch to C
    assert text(derivation.derive(g, 1)) == "B[C]X[A]C[Y]"


def test_right_context_brackets():
    g = grammar("A[C]B", "A > B --> X", "C > B --> Z")
    assert text(derivation.derive(g, 1)) == "X[C]B"    # A skips the branch; C meets the branch's end
    g = grammar("A[C]B", "A > [C]B --> X")
    assert text(derivation.derive(g, 1)) == "X[C]B"
    g = grammar("A[D]B", "A > [C]B --> X")
    assert text(derivation.derive(g, 1)) == "A[D]B"


def test_ignore_matters():
    prods = ("A > B --> X", "A < B --> Y")
    assert text(derivation.derive(grammar("A+-B", *prods), 1)) == "A+-B"
    g = grammar("A+-B", *prods, ignore="+ -")
    assert g.ignore == frozenset("+-")
    assert text(derivation.derive(g, 1)) == "X+-Y"
    assert grammar("A", "A --> A", ignore="+-F").ignore == frozenset("+-F")


def test_context_parameters_bind():
    g = grammar("A(2)B(3)C(5)", "A(x) < B(y) > C(z) --> B(x*y+z)")
    assert derivation.derive(g, 1).modules[1] == Module("B", (11.0,))


# ---------------------------------------------------------------- parameters

def test_parametric_condition_stops_growth():
    g = grammar("A(1)", "A(x) : x < 6 --> A(x+1) B(x)", n=8)
    d = derivation.derive(g)
    assert d.modules[0] == Module("A", (6.0,))
    assert [m.params[0] for m in d.modules[1:]] == [5.0, 4.0, 3.0, 2.0, 1.0]
    assert d.lengths == [1, 2, 3, 4, 5, 6, 6, 6, 6]


def test_omitted_length_reaches_fixpoint():
    g = grammar("A(1) B", "A(x) : x < 6 --> A(x+1) B(x)")
    assert g.derivation_length is None
    assert derivation.check_termination(g) == 5
    d = derivation.derive(g)
    assert d.steps == 5 and d.modules[0] == Module("A", (6.0,)) and len(d.modules) == 7
    assert derivation.count(g).length == 7


def test_expressions():
    g = grammar("A(2, 3)", "A(x, y) : x < y and not x == 3 --> B(x**2 + -y, sqrt(16), min(x, y, 1), "
                "sin(90), floor(2.7), (x + y) * 2 / 4, x > 1)")
    assert derivation.derive(g, 1).modules == [Module("B", (1.0, 4.0, 1.0, 1.0, 2.0, 2.5, 1.0))]
    g = grammar("A(3)", "A(x) : x < 3 --> B")
    assert derivation.derive(g, 1).modules == [Module("A", (3.0,))]
    # arity mismatch: A(x) does not match A(1, 2), which is copied
    assert derivation.derive(grammar("A(1, 2) A(3)", "A(x) --> B(x)"), 1).modules == [
        Module("A", (1.0, 2.0)), Module("B", (3.0,))]


def test_division_by_zero_names_the_line():
    with pytest.raises(L.LSystemError, match=r"test.lsys: line 3: .*division by zero while rewriting A\(0\)"):
        derivation.derive(grammar("A(0)", "A(x) --> A(1 / x)"), 1)


def test_organs_and_at_modules():
    g = grammar('~(leaf, 0.5) @O(2) ~("big leaf") !(0.1)F', "A --> ~(petal, 2 * 3)")
    assert g.axiom == (Module("~", ("leaf", 0.5)), Module("@O", (2.0,)), Module("~", ("big leaf",)),
                       Module("!", (0.1,)), Module("F"))
    g = grammar("A ~(leaf)", "A --> ~(petal, 2 * 3)", "~(leaf) --> ~(leaf, 1)")
    assert derivation.derive(g, 1).modules == [Module("~", ("petal", 6.0)), Module("~", ("leaf", 1.0))]


def test_header():
    g = L.parse("""# a comment
    Axiom: A(1) B   # trailing comment
    Derivation Length: 8
    angle: 22.5
    ignore: + - F
    seed: 7
    width: 0.25
    ol stub: A
    ol stub: @O levels 2 3
    production:
    A(x) : x < 6 --> A(x+1) B(x)

    b < a > c --> b
    endlsystem
    this line is not read
    """, name="tree.lsys")
    assert g.axiom == (Module("A", (1.0,)), Module("B"))
    assert (g.derivation_length, g.angle, g.seed, g.width, g.source_name) == (8, 22.5, 7, 0.25, "tree.lsys")
    assert g.ignore == frozenset("+-F")
    assert g.ol_stubs == (L.OLStub("A", None), L.OLStub("@O", (2, 3)))
    assert len(g.productions) == 2 and not g.is_context_free and not g.is_stochastic
    d = grammar("F")
    assert (d.derivation_length, d.angle, d.seed, d.width, d.ol_stubs) == (None, 90.0, 0, 0.1, ())


# ---------------------------------------------------------------- the generator

def test_generator_golden_values():
    # splitmix64 from state 0 gives the reference sequence e220a839..., 6e789e6a...
    assert L.splitmix64(0) == 0xE220A8397B1DCDAF
    assert L.child_hash(0, 0) == 0x6E789E6AA1B965F4
    assert L.splitmix64(1) == 0x910A2DEC89025CC1
    assert L.child_hash(12345, 3) == 0xBF507EA59B3CBD70
    assert L.root_hash(7, 0) == 0x6E7CE04A63AC7DD2
    assert L.draw(0) == 0.17601256256594233
    assert L.draw(L.root_hash(7, 0)) == 0.13170620676727351
    h = np.array([0, 1, 12345, 2 ** 64 - 1], np.uint64)
    j = np.array([0, 5, 3, 7])
    assert L.child_hash_array(h, j).tolist() == [L.child_hash(int(a), int(b)) for a, b in zip(h, j)]
    assert L.draw_array(h).tolist() == [L.draw(int(a)) for a in h]


STOCHASTIC = ("F --> F[+F]F : 0.6", "F --> F[-F]F : 0.4")


def test_stochastic_is_reproducible():
    a, b = (derivation.derive(grammar("F", *STOCHASTIC, n=6, seed=7)) for _ in range(2))
    assert text(a) == text(b) and np.array_equal(a.hashes, b.hashes)
    c = derivation.derive(grammar("F", *STOCHASTIC, n=6, seed=8))
    assert text(a) != text(c)
    g = grammar("F", *STOCHASTIC, n=6, seed=7)
    assert g.is_stochastic and g.is_context_free


def test_stochastic_frequency_within_3_sigma():
    n = 10_000
    d = derivation.derive(grammar("F" * n, *STOCHASTIC, n=1, seed=3))
    s = symbols(d)
    assert s["+"] + s["-"] == n
    assert abs(s["+"] / n - 0.6) < 3 * math.sqrt(0.6 * 0.4 / n)


def test_choices_follow_the_hash_contract():
    # what the DCSG recomputes: the successor of axiom module i is rewrite(m, root_hash),
    # successor module j gets child_hash(h, j), and the pick is draw(h) against 0.6
    g = grammar("FFFF", *STOCHASTIC, n=2, seed=11)
    one = derivation.derive(g, 1)
    k = 0
    for i, m in enumerate(g.axiom):
        h = L.root_hash(11, i)
        succ = g.rewrite(m, h)
        assert succ == one.modules[k:k + len(succ)]
        assert succ[2].symbol == ("+" if L.draw(h) < 0.6 else "-")
        assert one.hashes[k:k + len(succ)].tolist() == [L.child_hash(h, j) for j in range(len(succ))]
        k += len(succ)
    expect = []                         # step 2 from step 1's modules and hashes alone
    for m, h in zip(one.modules, one.hashes.tolist()):
        expect += g.rewrite(m, h) or [m]
    assert derivation.derive(g).modules == expect
    assert [(p.text, w) for p, w in g.alternatives(Module("F"))] == [(STOCHASTIC[0], 0.6), (STOCHASTIC[1], 0.4)]
    assert g.alternatives(Module("+")) == [] and g.rewrite(Module("+"), 1) is None


def test_stochastic_expected_counts():
    c = derivation.count(grammar("F", *STOCHASTIC, n=3))
    assert not c.exact and c.per_symbol["F"] == 27.0
    c1 = derivation.count(grammar("F", *STOCHASTIC, n=1))
    assert c1.per_symbol["+"] == pytest.approx(0.6) and c1.per_symbol["-"] == pytest.approx(0.4)


def test_deterministic_first_match_wins():
    g = grammar("A(1)", "A(x) : x > 0 --> B", "A(x) --> C")
    assert derivation.derive(g, 1).modules == [Module("B")]
    assert [p.line for p, _ in g.alternatives(Module("A", (1.0,)))] == [3]
    assert g.rewrite(Module("A", (-1.0,)), 0) == [Module("C")]


# ---------------------------------------------------------------- errors

def syntax_error(text, line, column):
    with pytest.raises(L.LSystemSyntaxError) as e:
        L.parse(text, name="tree.lsys")
    assert f"tree.lsys: line {line}, column {column}:" in str(e.value), str(e.value)
    assert (e.value.line, e.value.column) == (line, column)
    assert isinstance(e.value, SceneError) and isinstance(e.value, ValueError)
    return str(e.value)


def test_syntax_errors_point_at_the_token():
    head = "axiom: A(1)\nderivation length: 3\nproduction:\n"
    assert "expected ')'" in syntax_error(head + "A(x) --> B(x + 1 C\n", 4, 11)
    assert "undefined parameter 'y'" in syntax_error(head + "A(x) --> B(x) C(y)\n", 4, 17)
    assert "undefined parameter 'z'" in syntax_error(head + "\n# c\nA(x) : z > 1 --> B\n", 6, 8)
    assert "'**'" in syntax_error(head + "A(x) --> B(x ^ 2)\n", 4, 14)
    assert "expected an operator" in syntax_error(head + "A(x) --> B(x 2)\n", 4, 14)
    assert "'-->'" in syntax_error(head + "A(x) B\n", 4, 7)
    assert "unknown header 'colour'" in syntax_error("axiom: F\ncolour: red\n", 2, 1)
    assert "whole number" in syntax_error("axiom: F\nderivation length: 2.5\n", 2, 20)
    assert "undefined parameter" in syntax_error("axiom: A(x)\n", 1, 10)
    assert "one predecessor" in syntax_error(head + "A B --> C\n", 4, 3)
    assert "bound twice" in syntax_error(head + "A(x) < B(x) --> C\n", 4, 10)
    assert "missing 'axiom:'" in syntax_error("production:\nA --> B\n", 1, 1)
    assert "mix" in syntax_error(head + "F --> F : 0.5\nF --> G\n", 5, 3)
    assert "mix" in syntax_error(head + "F --> G\nF --> F : 0.5\n", 5, 11)
    assert "unknown function" in syntax_error(head + "A(x) --> B(foo(x))\n", 4, 12)


def test_runaway_growth_is_refused_before_allocating():
    g = grammar("F", "F --> F[+F]F[-F]F", n=9)
    with pytest.raises(L.LSystemGrowthError) as e:
        derivation.derive(g, cap=1000)
    msg = str(e.value)
    assert "step 4 would derive 1,561 modules (cap 1,000)" in msg and "DCSG" in msg
    assert derivation.count(g).length == 5 ** 9 + 6 * (5 ** 9 - 1) // 4     # counted lazily instead
    cs = grammar("A", "A > B --> A", "A --> AAA", n=20)
    with pytest.raises(L.LSystemGrowthError) as e:
        derivation.derive(cs, cap=100)
    assert "step 5 would derive 243 modules (cap 100)" in str(e.value) and "DCSG" not in str(e.value)


@pytest.mark.parametrize("prods, chain", [(("A --> B", "B --> A"), "A -> B -> A"),
                                          (("A --> A B",), "A -> A")])
def test_recursion_without_length_names_the_symbol(prods, chain):
    g = grammar("A", *prods)
    for f in (derivation.check_termination, derivation.derive, derivation.count):
        with pytest.raises(L.LSystemRecursionError, match=f"symbol A rewrites forever \\({chain}\\)"):
            f(g)
    assert len(derivation.derive(g, 3).modules) > 0      # a derivation length is fine


def test_too_long_and_context_sensitive_recursion():
    with pytest.raises(L.LSystemRecursionError, match="symbol A needs more than 1000 steps"):
        derivation.check_termination(grammar("A(0)", "A(x) : x < 5000 --> A(x + 1)"))
    assert derivation.check_termination(grammar("A(0)", "A(x) : x < 1000 --> A(x + 1)")) == 1000
    with pytest.raises(L.LSystemRecursionError, match="no fixpoint after 1000 steps"):
        derivation.derive(grammar("ba", "b < a --> c", "c --> a"))     # b a, b c, b a, ...


def test_termination_budget_and_load(tmp_path):
    g = grammar("A(0, 0)", "A(x, y) : x < 12 --> A(x + 1, y) A(x + 1, y + 1)")
    assert derivation.check_termination(g, budget=10) is None      # undecided: derive still bounds it
    assert derivation.check_termination(g) == 12
    assert derivation.count(g).length == len(derivation.derive(g).modules) == 2 ** 12
    p = tmp_path / "tree.lsys"
    p.write_text("axiom: A\nproduction:\nA --> B(q)\n")
    with pytest.raises(L.LSystemSyntaxError, match=r"^tree.lsys: line 3, column 9: undefined parameter 'q'"):
        L.load(p)
    with pytest.raises(L.LSystemError, match="cannot read"):
        L.load(tmp_path / "missing.lsys")


def test_production_apply_with_context():
    g = grammar("A", "A(x) < B(y) --> C(x + y)")
    (prod,) = g.productions
    assert prod.apply(Module("B", (2.0,)), left=[Module("A", (1.0,))]) == [Module("C", (3.0,))]
    with pytest.raises(L.LSystemError, match="does not fit"):
        prod.apply(Module("B", (2.0,)))
    with pytest.raises(L.LSystemError, match="context-free"):
        g.alternatives(Module("B", (2.0,)))
