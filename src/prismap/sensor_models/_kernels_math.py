"""numba helpers of every sensor model kernel: log-space sums, the normal CDF, logit and sigmoid, and
vectorisable exp and log.

Every kernel of this package releases the GIL (``nogil=True``), so the grid's model calls run beside its
GIL-free casting. :func:`exp_into` and :func:`log_into` are polynomial (Cephes) routines in loops LLVM
vectorises, since neither numpy's float64 exp/log nor numba's ``math.exp`` is SIMD on a CPU without AVX-512
(numba would need Intel's SVML).
"""

import math

import numba as nb
import numpy as np
from numba.core import types
from numba.extending import intrinsic

_SQRT_HALF = math.sqrt(0.5)


# --------------------------------------------------------------------------------------------- helpers


@nb.njit(cache=True, nogil=True)
def logaddexp(a, b):
    """``log(exp(a) + exp(b))``, exact for -inf arguments."""
    if a < b:
        a, b = b, a
    if not b - a >= _EXP_ZERO:  # exp(b - a) is 0 (libm's slow underflow path): nothing to add
        return a
    return a + math.log1p(math.exp(b - a))


@nb.njit(cache=True, nogil=True)
def log1mexp(t):
    """``log(1 - exp(t))`` for ``t <= 0`` (``t > 0`` is treated as 0, giving -inf)."""
    if t >= 0.0:
        return -np.inf
    if t > -0.6931471805599453:
        return math.log(-math.expm1(t))
    return math.log1p(-math.exp(t))


@nb.njit(cache=True, nogil=True)
def normal_cdf(x):
    """Standard normal CDF."""
    return 0.5 * math.erfc(-x * _SQRT_HALF)


@nb.njit(cache=True, nogil=True)
def _logit(p):
    return math.log(p) - math.log1p(-p)


@nb.njit(cache=True, nogil=True)
def _sigmoid(x):
    if x >= 0.0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


# ------------------------------------------------------------------------------ vectorisable exp, log
# Cephes' exp and log (S. L. Moshier, "Methods and programs for mathematical functions", 1989): range
# reduction by bit operations on the float64 representation, then a rational approximation. Written
# without calls and with selects instead of branches, so that a loop over an array of them vectorises
# (4 lanes with AVX2). ``error_model="numpy"``: numba's default checks every division for zero, a branch
# that stops the vectoriser. Never inline them into a fastmath function: reassociation turns the rounding
# ``(y / ln 2 + shifter) - shifter`` into ``y / ln 2`` and undoes the two-constant (Cody-Waite) reduction.


def _bitcast(source, target):
    """An intrinsic reinterpreting the bits of a ``source`` scalar as a ``target`` one (no instruction)."""

    @intrinsic
    def cast(typingctx, x):
        if x != source:
            return None

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(target))

        return target(source), codegen

    return cast


_float_bits = _bitcast(types.float64, types.int64)
"""The IEEE-754 bits of a float64 as an int64."""
_bits_float = _bitcast(types.int64, types.float64)
"""The float64 whose IEEE-754 bits are the given int64."""


_LOG2E = 1.4426950408889634
_SHIFTER = 6755399441055744.0  # 1.5 * 2^52: adding it rounds to an integer held in the low mantissa bits
_LN2_HI = 6.93145751953125e-1  # ln 2 = _LN2_HI + _LN2_LO, _LN2_HI with a short mantissa (exact n * _LN2_HI)
_LN2_LO = 1.42860682030941723212e-6
_EXP_ZERO = -745.1332191019412  # below: exp rounds to 0
_EXP_MAX = 709.782712893384  # above: exp overflows
_EXP_NORMAL = -708.3964185322641  # below: exp is subnormal or 0, which added to a sum >= 1 changes nothing


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def fast_exp(x):
    """``exp(x)`` to 2 ulp (Cephes' Pade form on ``|r| <= ln(2) / 2``, ``x = n ln 2 + r``), subnormal results
    rounded once; 0 below -745.13, inf above 709.78, NaN for NaN."""
    y = min(max(x, _EXP_ZERO), _EXP_MAX)
    t = y * _LOG2E + _SHIFTER
    n = t - _SHIFTER  # round(y / ln 2)
    r = (y - n * _LN2_HI) - n * _LN2_LO
    rr = r * r
    p = r * ((1.26177193074810590878e-4 * rr + 3.02994407707441961300e-2) * rr + 9.99999999999999999910e-1)
    q = ((3.00198505138664455042e-6 * rr + 2.52448340349684104192e-3) * rr + 2.27265548208155028766e-1) * rr + 2.0
    k = _float_bits(t) - _float_bits(_SHIFTER)  # n as an integer, in [-1075, 1024]
    half = k >> 1  # 2^n as 2^half 2^(k - half): both normal at either end of the range
    out = (1.0 + 2.0 * p / (q - p)) * _bits_float((half + 1023) << 52) * _bits_float((k - half + 1023) << 52)
    out = 0.0 if x < _EXP_ZERO else out
    out = np.inf if x > _EXP_MAX else out
    return x if x != x else out


_SUBNORMAL_SCALE = 18014398509481984.0  # 2^54
_MANTISSA = 0x000FFFFFFFFFFFFF
_HALF_EXPONENT = 0x3FE0000000000000  # the exponent bits of 0.5
_EXPONENT_AS_FLOAT = 0x4330000000000000  # the bits of 2^52: OR an integer below 2^52 in, subtract 2^52
_TWO_52 = 4503599627370496.0
_SQRT_HALF_EXACT = 0.70710678118654752440


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def fast_log(x):
    """``log(x)`` to 2 ulp for every positive float64, subnormals included (Cephes' rational form on the
    mantissa in ``[sqrt(1/2), sqrt(2))``); -inf at 0, inf at inf, NaN below 0 and for NaN."""
    sub = x < 2.2250738585072014e-308
    b = _float_bits(x * _SUBNORMAL_SCALE if sub else x)
    # the exponent as a float without an int64 -> float64 conversion (AVX2 has none for packed int64)
    e = _bits_float(((b >> 52) & 0x7FF) | _EXPONENT_AS_FLOAT) - (_TWO_52 + 1022.0) - (54.0 if sub else 0.0)
    m = _bits_float((b & _MANTISSA) | _HALF_EXPONENT)  # x = m 2^e, m in [0.5, 1)
    low = m < _SQRT_HALF_EXACT
    e = e - 1.0 if low else e
    m = (m + m - 1.0) if low else (m - 1.0)
    z = m * m
    p = (
        (
            ((1.01875663804580931796e-4 * m + 4.97494994976747001425e-1) * m + 4.70579119878881725854e0) * m
            + 1.44989225341610930846e1
        )
        * m
        + 1.79368678507819816313e1
    ) * m + 7.70838733755885391666e0
    q = (
        (((m + 1.12873587189167450590e1) * m + 4.52279145837532221105e1) * m + 8.29875266912776603211e1) * m
        + 7.11544750618563894466e1
    ) * m + 2.31251620126765340583e1
    y = m * (z * p / q) - e * 2.121944400546905827679e-4 - 0.5 * z
    out = (m + y) + e * 0.693359375
    if not (x > 0.0 and x < np.inf):
        out = -np.inf if x == 0.0 else (x if x == np.inf else np.nan)
    return out


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def fast_log1mexp(t):
    """``log(1 - exp(t))`` for ``t <= -ln 2`` (relative error below 2e-12; use :func:`log1mexp` nearer 0, where
    ``1 - e^t`` cancels) by :func:`fast_exp` and :func:`fast_log`, branch-free, so that a loop over it vectorises:
    the series ``-u (1 + u (1/2 + u/3))`` (``u = e^t``) below ``u = 1e-4`` (truncation ``u^3 / 4``), where
    ``log(1 - u)`` would lose digits, ``fast_log(1 - u)`` above."""
    u = fast_exp(t)
    series = -u * (1.0 + u * (0.5 + u * (1.0 / 3.0)))
    return series if u < 1e-4 else fast_log(1.0 - u)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def exp_into(x, out, n):
    """``out[:n] = exp(x[:n])`` by :func:`fast_exp` (a vectorised loop)."""
    for i in range(n):
        out[i] = fast_exp(x[i])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def log_into(x, out, n):
    """``out[:n] = log(x[:n])`` by :func:`fast_log` (a vectorised loop)."""
    for i in range(n):
        out[i] = fast_log(x[i])
