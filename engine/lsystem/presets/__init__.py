"""Grammar presets: one `<name>.lsys` file per preset in this package, in the
grammar format of engine/lsystem/grammar.py, each opening with a comment that says
what it draws and where it comes from (ABOP = Prusinkiewicz & Lindenmayer,
The Algorithmic Beauty of Plants; the thesis's equations and figures).

The files live inside the package so that they ship in the extension zip;
they are read with importlib.resources (a plain file next to this module
in a source checkout or an installed extension). Every preset is context
free and deterministic, so it renders through the cyclic scene graph
(engine/geometry/dcsg.py) without deriving its string.
"""
from importlib import resources

from ..grammar import LSystemError, parse

# name -> (label, description), in menu order (the first is the default)
PRESETS = {
    "abop_1_24a": ("ABOP 1.24a (bracketed plant)",
                   "ABOP fig. 1.24a: F --> F[+F]F[-F]F, 25.7 degrees, n = 5 (3125 segments)"),
    "abop_1_24b": ("ABOP 1.24b (bracketed plant)",
                   "ABOP fig. 1.24b: F --> F[+F]F[-F][F], 20 degrees, n = 5 (3125 segments)"),
    "abop_1_24c": ("ABOP 1.24c (bracketed plant)",
                   "ABOP fig. 1.24c: F --> FF-[-F+F+F]+[+F-F-F], 22.5 degrees, n = 4 (4096 segments)"),
    "abop_1_24d": ("ABOP 1.24d (bracketed plant)",
                   "ABOP fig. 1.24d: X --> F[+X]F[-X]+X, F --> FF, 20 degrees, n = 7"),
    "abop_1_24e": ("ABOP 1.24e (bracketed plant)",
                   "ABOP fig. 1.24e: X --> F[+X][-X]FX, F --> FF, 25.7 degrees, n = 7"),
    "abop_1_24f": ("ABOP 1.24f (bracketed plant)",
                   "ABOP fig. 1.24f: X --> F-[[X]+X]+F[+FX]-X, F --> FF, 22.5 degrees, n = 5"),
    "hilbert_3d": ("3D Hilbert curve",
                   "ABOP fig. 1.14: the three-dimensional Hilbert curve, n = 3 (511 segments)"),
    "ternary_tree": ("Ternary tree (ABOP 2.8a)",
                     "ABOP fig. 2.8a: a tree with ternary branching, widths growing with age, "
                     "without tropism, n = 6 (1457 segments)"),
    "sympodial_tree": ("Sympodial tree (thesis 8.5)",
                       "After the thesis's fig. 8.5: a stem ruleset and a sympodial branch ruleset "
                       "(ABOP fig. 2.7) with twigs and leaf organs, about 42 000 segments, "
                       "one OL stub per main branch"),
    "sierpinski_tetrahedron": ("Sierpinski tetrahedron",
                               "Thesis eq. 4.1: four half-size copies at the corners, level 6 "
                               "(4096 spheres)"),
    "menger_sponge": ("Menger sponge",
                      "20 sub-cubes of a third the side, level 3 (8000 boxes)"),
    "sphereflake": ("Sphereflake",
                    "Haines's sphereflake (thesis fig. 8.3): 9 spheres of a third the radius on "
                    "each sphere, level 4 (7381 spheres)"),
}


def _unknown(name):
    return LSystemError(f"L-system preset {name!r}: unknown (known: {', '.join(PRESETS)})")


def preset_text(name):
    """The grammar text of preset `name` (a key of PRESETS)."""
    if name not in PRESETS:
        raise _unknown(name)
    return resources.files(__name__).joinpath(f"{name}.lsys").read_text(encoding="utf-8")


def load_preset(name):
    """The parsed Grammar of preset `name`; errors name its file."""
    return parse(preset_text(name), name=f"{name}.lsys")
