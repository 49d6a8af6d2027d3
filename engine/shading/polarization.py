"""Polarization (thesis Appendix A.2): Fresnel with retardance, Stokes vectors, Mueller matrices.

Light's polarization state is a Stokes vector S = (S0, S1, S2, S3) in a
reference frame: a unit vector x across the ray d (y = d × x completes it;
angles across the ray go from x toward y).
With the field's components E_x, E_y,

    S0 = |E_x|² + |E_y|²,  S1 = |E_x|² - |E_y|²,  S2 = 2 Re(E_x E_y*),  S3 = 2 Im(E_x E_y*).

An element acting on the field by a Jones matrix J acts on S by the Mueller
matrix M = U (J ⊗ J*) U⁻¹ (`mueller_of_jones`, what the tests pin every other
matrix here to). Frames turn with the ray: before an interaction, S is rotated
into the frame whose x is the s direction (perpendicular to the plane of
incidence), where a specular reflection is diagonal in Jones terms:
J = diag(r_s, r_p).

Fresnel with retardance follows the thesis's eq. A.3 (real arithmetic, a
complex index n + ik): with 2a² = √((n² - k² - sin²θ)² + 4n²k²) + (n² - k² - sin²θ)
and 2b² = the same root minus that term,

    F_s = (a² + b² - 2a cosθ + cos²θ) / (a² + b² + 2a cosθ + cos²θ)
    F_p = F_s (a² + b² - 2a sinθ tanθ + sin²θ tan²θ) / (a² + b² + 2a sinθ tanθ + sin²θ tan²θ)
    tan δ_s = 2b cosθ / (cos²θ - a² - b²)
    tan δ_p = 2 cosθ ((n² - k²) b - 2nka) / ((n² + k²)² cos²θ - a² - b²)

with δ = -arg r, the phase lag of the reflected field (the thesis's sign).
(Some statements of tan δ_p carry a factor b in its numerator; the complex
amplitudes r_s, r_p, which the tests check against, have none.)

Conductors: complex indices near 560 nm (Cu, Au, Al: Palik's tables, as
Mitsuba ships them); one index for all wavelengths.
"""
import math

import numpy as np
from numba import njit

# complex index (n, k) of metals near 560 nm: normal-incidence reflectance 0.6725, 0.8776, 0.9200
CONDUCTORS = {"Cu": (0.826, 2.599), "Au": (0.306, 2.880), "Al": (1.020, 6.850)}

# U of M = U (J ⊗ J*) U⁻¹, for the Stokes convention above
_U = np.array([[1, 0, 0, 1], [1, 0, 0, -1], [0, 1, 1, 0], [0, -1j, 1j, 0]], np.complex128)
_U_INV = np.linalg.inv(_U)


@njit(cache=True)
def fresnel(cos_i, n, k):
    """(F_s, F_p, δ_s, δ_p) of a reflection at incidence cos_i onto index n + ik (relative
    to the side the light comes from; n < 1 from inside a denser dielectric, where past
    the critical angle F = 1 with a phase), thesis eq. A.3. Scalars (the kernels' form)."""
    c = min(max(cos_i, 0.0), 1.0)
    s2 = 1.0 - c * c
    q = n * n - k * k - s2
    root = math.sqrt(q * q + 4.0 * n * n * k * k)
    a = math.sqrt(max(root + q, 0.0) / 2.0)
    b = math.sqrt(max(root - q, 0.0) / 2.0)
    ab = a * a + b * b
    f_s = (ab - 2.0 * a * c + c * c) / (ab + 2.0 * a * c + c * c)
    st = s2 / max(c, 1e-300)                                      # sinθ tanθ
    f_p = f_s * (ab - 2.0 * a * st + st * st) / (ab + 2.0 * a * st + st * st) if c > 0.0 else f_s
    d_s = math.atan2(2.0 * b * c, c * c - ab)
    d_p = math.atan2(2.0 * c * ((n * n - k * k) * b - 2.0 * n * k * a), (n * n + k * k) ** 2 * c * c - ab)
    return f_s, f_p, d_s, d_p


def fresnel_retardance(cos_i, n, k=0.0):
    """`fresnel` over an array of incidence cosines -> four arrays (F_s, F_p, δ_s, δ_p)."""
    c = np.asarray(cos_i, np.float64)
    out = np.array([fresnel(float(x), float(n), float(k)) for x in c.reshape(-1)]).reshape(c.shape + (4,))
    return tuple(out[..., j] for j in range(4))


def fresnel_amplitudes(cos_i, n, k=0.0):
    """The complex reflection amplitudes (r_s, r_p) of the same interface."""
    c = np.clip(np.asarray(cos_i, np.float64), 0.0, 1.0)
    eta = complex(n, k)
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / eta ** 2 + 0j)
    return (c - eta * cos_t) / (c + eta * cos_t), (eta * c - cos_t) / (eta * c + cos_t)


def mueller_of_jones(J):
    """The real 4 x 4 Mueller matrix of a 2 x 2 Jones matrix J (in the Stokes convention above)."""
    J = np.asarray(J, np.complex128)
    return np.real(_U @ np.kron(J, J.conj()) @ _U_INV)


@njit(cache=True)
def reflection_terms(f_s, f_p, d_s, d_p):
    """(A, B, C, S) of a specular reflection's Mueller matrix (`reflection`)."""
    m = math.sqrt(max(f_s * f_p, 0.0))
    return 0.5 * (f_s + f_p), 0.5 * (f_s - f_p), m * math.cos(d_s - d_p), -m * math.sin(d_s - d_p)


@njit(cache=True)
def transmission_terms(f_s, f_p):
    """(A, B, C, S) of a dielectric transmission's Mueller matrix (`transmission`; S = 0)."""
    t_s, t_p = 1.0 - f_s, 1.0 - f_p
    return 0.5 * (t_s + t_p), 0.5 * (t_s - t_p), math.sqrt(max(t_s * t_p, 0.0)), 0.0


def _matrix(A, B, C, S):
    return np.array([[A, B, 0.0, 0.0], [B, A, 0.0, 0.0], [0.0, 0.0, C, -S], [0.0, 0.0, S, C]])


def reflection(f_s, f_p, d_s, d_p):
    """Mueller matrix of a specular reflection, in the frame whose x is the s direction:
    [[A, B, 0, 0], [B, A, 0, 0], [0, 0, C, -S], [0, 0, S, C]], A, B = (F_s ± F_p)/2,
    C + iS = √(F_s F_p) e^{-i(δ_s - δ_p)} (= r_s r_p*)."""
    return _matrix(*reflection_terms(f_s, f_p, d_s, d_p))


def transmission(f_s, f_p):
    """Mueller matrix of the light a dielectric interface lets through (no phase), as a
    radiance weight: T = 1 - F per component, so a grey path's S0 gets 1 - (F_s + F_p)/2."""
    return _matrix(*transmission_terms(f_s, f_p))


def rotator(phi):
    """Mueller matrix that re-expresses a Stokes vector in a frame turned by phi (radians,
    from x toward y = d × x) about the ray."""
    c, s = math.cos(2.0 * phi), math.sin(2.0 * phi)
    return np.array([[1.0, 0.0, 0.0, 0.0], [0.0, c, s, 0.0], [0.0, -s, c, 0.0], [0.0, 0.0, 0.0, 1.0]])


def linear_polarizer(theta):
    """Mueller matrix of an ideal linear polarizer whose axis makes angle theta with the frame's x."""
    c, s = math.cos(2.0 * theta), math.sin(2.0 * theta)
    return 0.5 * np.array([[1.0, c, s, 0.0], [c, c * c, c * s, 0.0], [s, c * s, s * s, 0.0], [0.0, 0.0, 0.0, 0.0]])


@njit(cache=True)
def turn_angle(f0, f1, f2, t0, t1, t2, d0, d1, d2):
    """The angle that turns frame vector f into t about the ray direction d (both across d),
    from x toward d × x: the argument of `rotator` (scalars, the kernels' form)."""
    c0, c1, c2 = f1 * t2 - f2 * t1, f2 * t0 - f0 * t2, f0 * t1 - f1 * t0
    return math.atan2(c0 * d0 + c1 * d1 + c2 * d2, f0 * t0 + f1 * t1 + f2 * t2)


def frame_angle(x_from, x_to, d):
    """turn_angle of three vectors."""
    return turn_angle(*(float(c) for v in (x_from, x_to, d) for c in v))


def s_direction(d, n):
    """The s direction of a ray d meeting a surface of normal n: d × n normalised (any
    vector across d at normal incidence, where s and p are one)."""
    s = np.cross(d, n)
    ln = np.linalg.norm(s)
    if ln < 1e-12:
        helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        s = np.cross(d, helper)
        ln = np.linalg.norm(s)
    return s / ln


def degree_of_polarization(S):
    """√(S1² + S2² + S3²) / S0 (0 for no light)."""
    S = np.asarray(S, np.float64)
    return float(np.sqrt(S[1] ** 2 + S[2] ** 2 + S[3] ** 2) / S[0]) if S[0] > 0.0 else 0.0


# ------------------------------------------------------------------ along paths
# A path that traces polarization keeps, per band, a Stokes vector (a photon) or
# what the camera measures as a row vector over the Stokes vector of the light
# arriving along its current segment (a camera path: the measured value is w · S),
# in one frame across the segment. Both are kept with their first entry 1 and their
# scale in the path's throughput per band, so the rest of the tracer is unchanged:
# lights, lightmaps and the world send unpolarized light, which a camera row meets
# as w0 L. Bands differ where a conductor's index does.
#
# pol (8 nb + 3 floats, `pol_size`): nb rows of 4, then the frame's x, then the
# Mueller terms (A, B, C, S) per band of the interaction at hand (`TERMS`).

@njit(cache=True)
def pol_size(nb):
    return 8 * nb + 3


@njit(cache=True)
def frame_at(nb):
    """Where pol keeps its frame's x."""
    return 4 * nb


@njit(cache=True)
def terms_at(nb):
    """Where pol keeps an interaction's (A, B, C, S) per band."""
    return 4 * nb + 3


@njit(cache=True)
def _set_frame(pol, nb, x, d):
    """The frame's x: x made perpendicular to d, unit."""
    k = x[0] * d[0] + x[1] * d[1] + x[2] * d[2]
    x0, x1, x2 = x[0] - k * d[0], x[1] - k * d[1], x[2] - k * d[2]
    ln = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    f = frame_at(nb)
    pol[f], pol[f + 1], pol[f + 2] = x0 / ln, x1 / ln, x2 / ln


@njit(cache=True)
def start_row(pol, tp, angle, filtered, xaxis, d):
    """A camera ray d, through a linear polarizer at `angle` from the camera's x axis
    (xaxis) where `filtered`: every band's row = the filter's first row, normalised
    (without a filter, what the camera measures is S0: (1, 0, 0, 0)), the frame x the
    camera's x across d; tp takes the row's scale (1/2: a filter passes half of
    unpolarized light)."""
    nb = tp.shape[0]
    c, s = (math.cos(2.0 * angle), math.sin(2.0 * angle)) if filtered else (0.0, 0.0)
    for b in range(nb):
        pol[4 * b], pol[4 * b + 1], pol[4 * b + 2], pol[4 * b + 3] = 1.0, c, s, 0.0
        if filtered:
            tp[b] *= 0.5
    _set_frame(pol, nb, xaxis, d)


@njit(cache=True)
def start_stokes(pol, power, polarized, axis, d):
    """A photon leaving a light along d: unpolarized, or where `polarized`, through a linear
    polarizer whose axis is `axis` (a world direction; the light passes along its part
    across d): S = (1, 1, 0, 0) in the frame of that part. (The light's power is what
    passes the polarizer: compile_lights halves it.)"""
    nb = power.shape[0]
    k = axis[0] * d[0] + axis[1] * d[1] + axis[2] * d[2]
    across = (axis[0] - k * d[0]) ** 2 + (axis[1] - k * d[1]) ** 2 + (axis[2] - k * d[2]) ** 2
    # along the axis every direction across is the axis's: unpolarized as seen from there
    polarized = polarized and across > 1e-18
    for b in range(nb):
        pol[4 * b], pol[4 * b + 1], pol[4 * b + 2], pol[4 * b + 3] = 1.0, 1.0 if polarized else 0.0, 0.0, 0.0
    if polarized:
        _set_frame(pol, nb, axis, d)
    else:
        _set_frame(pol, nb, (1.0, 0.0, 0.0) if abs(d[0]) < 0.9 else (0.0, 1.0, 0.0), d)


@njit(cache=True)
def depolarize(pol, nb):
    """A rough or diffuse interaction: the light it sends is taken as unpolarized."""
    for b in range(nb):
        pol[4 * b + 1], pol[4 * b + 2], pol[4 * b + 3] = 0.0, 0.0, 0.0


@njit(cache=True)
def s_frame(pol, nb, d_in, n):
    """The s direction of light travelling along d_in onto normal n: across the plane of
    incidence (the frame's own x at normal incidence, where s and p are one)."""
    sx, sy, sz = d_in[1] * n[2] - d_in[2] * n[1], d_in[2] * n[0] - d_in[0] * n[2], d_in[0] * n[1] - d_in[1] * n[0]
    ln = math.sqrt(sx * sx + sy * sy + sz * sz)
    if ln < 1e-9:
        f = frame_at(nb)
        return pol[f], pol[f + 1], pol[f + 2]
    return sx / ln, sy / ln, sz / ln


@njit(cache=True)
def _mueller_step(pol, scale, s, d, sign):
    """Every band's vector in pol (a Stokes vector, or a camera's row), turned from pol's
    frame into the s frame s about the ray d, then met by the band's Mueller terms in pol
    (sign -1: their transpose, what a row meets) and divided by their A; the scale of its
    first entry goes into scale[b], and pol's frame becomes s."""
    nb = scale.shape[0]
    f, t = frame_at(nb), terms_at(nb)
    phi = turn_angle(pol[f], pol[f + 1], pol[f + 2], s[0], s[1], s[2], d[0], d[1], d[2])
    c2, s2 = math.cos(2.0 * phi), math.sin(2.0 * phi)
    for b in range(nb):
        A, B, C, S = pol[t + 4 * b], pol[t + 4 * b + 1], pol[t + 4 * b + 2], sign * pol[t + 4 * b + 3]
        if not A > 0.0:
            continue
        r = 4 * b
        v0, v1, v2, v3 = pol[r], pol[r + 1] * c2 + pol[r + 2] * s2, -pol[r + 1] * s2 + pol[r + 2] * c2, pol[r + 3]
        x0 = (A * v0 + B * v1) / A
        scale[b] *= x0
        if x0 > 0.0:
            pol[r], pol[r + 1] = 1.0, (B * v0 + A * v1) / (A * x0)
            pol[r + 2], pol[r + 3] = (C * v2 - S * v3) / (A * x0), (S * v2 + C * v3) / (A * x0)
    pol[f], pol[f + 1], pol[f + 2] = s[0], s[1], s[2]


@njit(cache=True)
def camera_vertex(pol, tp, d_cam, d_next, n):
    """The camera path went along d_cam, met a smooth interface (normal n) and goes on along
    d_next, with the interaction's Mueller terms per band in pol (`terms_at`), in its s
    frame. w <- w · R · M / A (R turns the s frame into the segment's; A is M's
    unpolarized weight, which the path's throughput already has), the scale of w0
    into tp, the frame to the s direction."""
    s = s_frame(pol, tp.shape[0], (-d_next[0], -d_next[1], -d_next[2]), n)
    _mueller_step(pol, tp, s, (-d_cam[0], -d_cam[1], -d_cam[2]), -1.0)     # about the light's way to the camera


@njit(cache=True)
def photon_vertex(pol, power, d_in, d_out, n):
    """A photon came along d_in, met a smooth interface (normal n) and goes on along d_out,
    with the interaction's Mueller terms per band in pol. S <- M · R · S / A (R turns the
    photon's frame into the s frame), the scale of S0 into power, the frame to the s
    direction (across d_out too)."""
    _mueller_step(pol, power, s_frame(pol, power.shape[0], d_in, n), d_in, 1.0)


@njit(cache=True)
def arriving_light(pol, nb, b, axis, d):
    """What band b's camera row (frame in pol) measures of light that left a linear
    polarizer of world axis `axis` (see start_stokes) travelling along d, per unit of its
    S0: w · S, with S = (1, cos 2θ, sin 2θ, 0) and θ the axis's angle in the row's frame."""
    f = frame_at(nb)
    k = axis[0] * d[0] + axis[1] * d[1] + axis[2] * d[2]
    x0, x1, x2 = axis[0] - k * d[0], axis[1] - k * d[1], axis[2] - k * d[2]
    if x0 * x0 + x1 * x1 + x2 * x2 < 1e-18:
        return pol[4 * b]
    th = turn_angle(pol[f], pol[f + 1], pol[f + 2], x0, x1, x2, d[0], d[1], d[2])
    return pol[4 * b] + pol[4 * b + 1] * math.cos(2.0 * th) + pol[4 * b + 2] * math.sin(2.0 * th)
