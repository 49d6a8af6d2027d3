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


# ---------------------------------------------------------------- stack views
# A ray's scratch is one int32 array that the cores also read as float32,
# float64 and uint64. numba's `ndarray.view` checks sizes and strides on every
# call (~18 ns each, measured), which a core that runs per ray pays again and
# again; `reinterpret` makes the same view of a C-contiguous 1-D array without
# the checks (the caller's arrays always qualify: the stacks are made here).
from numba import types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.core.imputils import impl_ret_borrowed  # noqa: E402
from numba.extending import intrinsic  # noqa: E402
from numba.np.arrayobj import make_array, populate_array  # noqa: E402


def _reinterpret_as(dtype):
    @intrinsic
    def reinterpret(typingctx, arr):
        if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C"):
            return None
        out = types.Array(dtype, 1, "C")

        def codegen(context, builder, sig, args):
            src = make_array(sig.args[0])(context, builder, args[0])
            dst = make_array(out)(context, builder)
            size = context.get_abi_sizeof(context.get_data_type(dtype))
            src_size = context.get_abi_sizeof(context.get_data_type(arr.dtype))
            nbytes = builder.mul(src.nitems, context.get_constant(types.intp, src_size))
            n = builder.udiv(nbytes, context.get_constant(types.intp, size))
            item = context.get_constant(types.intp, size)
            populate_array(dst, data=builder.bitcast(src.data, dst.data.type),
                           shape=cgutils.pack_array(builder, [n]),
                           strides=cgutils.pack_array(builder, [item]),
                           itemsize=item, meminfo=src.meminfo, parent=src.parent)
            # a borrowed reference: the view keeps the array's memory alive as long as it
            return impl_ret_borrowed(context, builder, out, dst._getvalue())

        return out(arr), codegen
    return reinterpret


as_float32 = _reinterpret_as(types.float32)
as_float64 = _reinterpret_as(types.float64)
as_uint64 = _reinterpret_as(types.uint64)


# ------------------------------------------------------------- typed constants
@intrinsic
def typed(typingctx, x):
    """x with its plain type: int64 for the literal 0, bool for True. numba types a
    constant argument as a literal, and a call with a literal is a signature of its
    own, so a core called with `0` here and an int64 there compiles twice."""
    out = types.unliteral(x)

    def codegen(context, builder, sig, args):
        return context.cast(builder, args[0], sig.args[0], out)
    return out(x), codegen
