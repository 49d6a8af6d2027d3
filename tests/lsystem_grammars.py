"""Grammars and a reference area shared by the L-system tests (not a test module)."""
import numpy as np

ABOP_124A = """axiom: F
derivation length: {n}
angle: 25.7
production:
F --> F[+F]F[-F]F
"""

# stochastic and context-sensitive: neither fits the preview's per-symbol plan
STOCHASTIC = """axiom: F
derivation length: 4
angle: 22.5
seed: 3
production:
F --> F[+F]F : 0.33
F --> F[-F]F : 0.33
F --> F[&F][^F]F : 0.34
"""
CONTEXT = """axiom: F A F
derivation length: 3
angle: 30
production:
F < A --> F[+A]A
A --> F
"""

# parametric, tapering (frustums), spheres and material slots
TAPERED = """axiom: !(0.4) A(1)
derivation length: 5
angle: 30
production:
A(s) : s > 0.2 --> F(s) !(s * 0.1) [ + A(s * 0.7) ] [ - ;(1) A(s * 0.6) @O(0.05) ] / A(s * 0.8)
"""


def quadrature_area(flat, n=24):
    """Total area of flattened primitives (dcsg.Flattened) by the midpoint rule per chart."""
    from photon_lightmaps.engine.geometry.primitives import prim_nfaces, prim_point
    total = 0.0
    for kind, params, xf in zip(flat.kind, flat.params, flat.transform):
        L = xf[:, :3]
        cof = np.linalg.det(L) * np.linalg.inv(L).T
        for f in range(prim_nfaces(int(kind))):
            for i in range(n):
                for j in range(n):
                    q = prim_point(int(kind), params, f, (i + 0.5) / n, (j + 0.5) / n)
                    total += np.linalg.norm(cof @ np.cross(q[3:6], q[6:9])) / (n * n)
    return total
