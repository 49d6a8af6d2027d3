"""numba option presets, one copy for every kernel module.

`@njit(cache=True)` stays the plain default elsewhere; these two are for the
ray traversal and the ray-CSG code, which run per ray:

* INLINE: small helpers folded into their caller (no call overhead per ray);
  error_model="numpy" lets a float division by zero give inf/NaN instead of
  a Python exception check on every division.
* CORE: the traversal cores, compiled as real functions (each is inlined
  into many kernels otherwise, which multiplies compile time) and without
  NRT reference counting, since they allocate nothing.
"""
INLINE = dict(cache=True, error_model="numpy", inline="always")
CORE = dict(cache=True, error_model="numpy", _nrt=False)
