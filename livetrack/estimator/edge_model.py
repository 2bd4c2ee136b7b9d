"""Edge-formation model: a straight black/white edge seen through a Gaussian PSF and square unit pixels.

A pixel whose centre lies at signed distance ``u`` (px, positive on the bright side) from a straight edge
whose unit normal is ``(nx, ny)`` records

    I = clip(Lb + (Lw - Lb) * E(u; sigma, a, b), 0, S)

where ``E`` is the unit step blurred by a Gaussian of standard deviation ``sigma`` (px) and averaged over
the pixel's square footprint.  Projected on the normal, the uniform unit square becomes the convolution of
two boxes of widths ``a`` and ``b`` (``{a, b} = {|nx|, |ny|}``; the result is symmetric in a and b, so we
take ``a >= b``, hence ``a >= 1/sqrt(2)``).  With ``Phi``/``phi`` the standard normal CDF/pdf and

    F(s) = s Phi(s/sigma) + sigma phi(s/sigma)                          (F' = Phi(s/sigma))
    G(s) = (s^2 + sigma^2)/2 Phi(s/sigma) + s sigma/2 phi(s/sigma)     (G' = F)

the box-a average of the blurred step is ``f(u) = [F(u + a/2) - F(u - a/2)] / a`` and the box-b average of
that is

    E(u) = [G(u + (a+b)/2) - G(u + (a-b)/2) - G(u - (a-b)/2) + G(u - (a+b)/2)] / (a b).

For ``b -> 0`` the second difference cancels catastrophically, so below ``SMALL_B`` we use the expansion
``E = f + b^2/24 f'' + O(b^4 f'''' / 1920)`` instead (truncation error < 1e-9 for sigma >= 0.3 px).
By the heat equation, ``dE/dsigma = sigma * d2E/du2``, so every derivative needs only Phi and phi.
Above ``SMALL_B`` the rounding error of the second difference is of order 1e-12 for |u| < 10 px and sigma
< 5 px (|G| < 60, a b > 0.007).

Optionally the PSF has a known wide halo: ``(1 - f) G(sigma) + f G(sigma_h)``, a fraction ``f`` of the energy in
a Gaussian of fixed width ``sigma_h`` (lens scatter; see ``livetrack.sim.optics``).  Blur and pixel integration
are linear, so the response is the same mixture of two responses, ``(1 - f) E(u; sigma) + f E(u; sigma_h)``,
and so are its derivatives (``dE/dsigma`` only through the core).  The clip acts on the sum: under
over-exposure the samples seen unclipped lie on the dark side, where the halo's tail ``f C Phi(u / sigma_h)``
(C the contrast, ~k times the white level at exposure factor k) grows with the exposure and, unmodelled, pulls
the fitted edge into the dark side.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr

FloatArray = npt.NDArray[np.float64]

SMALL_B = 1e-2
"""Footprint width below which the small-``b`` expansion replaces the exact second difference."""

_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def footprint_widths(normals: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Box widths (a, b) of the unit pixel projected on the edge normal.

    normals: (..., 2) unit normals (nx, ny).  Returns two (...,) arrays, ``a = max(|nx|, |ny|)`` and
    ``b = min(|nx|, |ny|)``, so ``a >= b`` and ``a >= 1/sqrt(2)`` for unit normals.
    """
    n = np.abs(np.asarray(normals, dtype=np.float64))
    return np.maximum(n[..., 0], n[..., 1]), np.minimum(n[..., 0], n[..., 1])


def _exact(v, sig, a, b):
    """E, dE/du, d2E/du2 by the second difference of G (needs b >= SMALL_B); arguments broadcast.

    With the corner points s_j = v + (a+b)/2, v + (a-b)/2, v - (a-b)/2, v - (a+b)/2 and signs +, -, -, +:
    ab E = 1/2 sum(s^2 Phi) + sigma^2/2 sum(Phi) + sigma/2 sum(s phi),  ab E' = sum(s Phi) + sigma sum(phi),
    ab E'' = sum(Phi), where Phi, phi are taken at s_j / sigma and phi includes 1/sqrt(2 pi).
    """
    inv_sig = 1.0 / sig
    hp = 0.5 * (a + b)
    hm = 0.5 * (a - b)
    sums = None
    for h, sign in ((hp, 1.0), (hm, -1.0), (-hm, -1.0), (-hp, 1.0)):
        s = v + h
        z = np.empty(np.broadcast_shapes(np.shape(s), np.shape(inv_sig)))
        np.multiply(s, inv_sig, out=z)
        cdf = ndtr(z)
        np.multiply(z, z, out=z)
        np.multiply(z, -0.5, out=z)
        pdf = np.exp(z, out=z)
        s_cdf = s * cdf
        terms = (s * s_cdf, cdf, s * pdf, s_cdf, pdf)  # s^2 Phi, Phi, s phi, s Phi, phi
        if sums is None:
            sums = list(terms) if sign > 0 else [-t for t in terms]
        else:
            for i, t in enumerate(terms):
                if sign > 0:
                    sums[i] += t
                else:
                    sums[i] -= t
    s2_cdf, cdf_sum, s_pdf, s_cdf_sum, pdf_sum = sums
    inv_ab = 1.0 / (a * b)
    sig_c = sig * _INV_SQRT_2PI
    e = (0.5 * inv_ab) * (s2_cdf + (sig * sig) * cdf_sum + sig_c * s_pdf)
    e_u = inv_ab * (s_cdf_sum + sig_c * pdf_sum)
    return e, e_u, cdf_sum * inv_ab


def _small_b(v, sig, a, b):
    """E, dE/du, d2E/du2 by the expansion in b (for b < SMALL_B); arguments broadcast."""
    t1 = v + 0.5 * a
    t2 = v - 0.5 * a
    z1 = t1 / sig
    z2 = t2 / sig
    c1, c2 = ndtr(z1), ndtr(z2)
    p1 = _INV_SQRT_2PI * np.exp(-0.5 * z1 * z1)
    p2 = _INV_SQRT_2PI * np.exp(-0.5 * z2 * z2)
    inv_a = 1.0 / a
    f0 = (t1 * c1 - t2 * c2 + sig * (p1 - p2)) * inv_a
    f1 = (c1 - c2) * inv_a
    f2 = (p1 - p2) * inv_a / sig
    f3 = (z2 * p2 - z1 * p1) * inv_a / (sig * sig)
    f4 = ((z1 * z1 - 1.0) * p1 - (z2 * z2 - 1.0) * p2) * inv_a / (sig * sig * sig)
    c = b * b / 24.0
    return f0 + c * f2, f1 + c * f3, f2 + c * f4


def edge_response(
    u_px: npt.ArrayLike,
    sigma_px: npt.ArrayLike,
    a: npt.ArrayLike,
    b: npt.ArrayLike,
    derivatives: bool = False,
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """Normalised pixel response ``E(u)`` in [0, 1] to a blurred unit step, optionally with derivatives.

    u_px: signed distance (px) of the pixel centre from the edge, positive on the bright side.
    sigma_px: Gaussian PSF standard deviation (px), > 0.
    a, b: footprint box widths from :func:`footprint_widths` (``a >= b >= 0``, ``a > 0``).
    All four broadcast together to the output shape.

    Returns ``E``, or ``(E, dE/du, dE/dsigma)`` when ``derivatives`` is True (the derivative with respect to
    the edge position ``d`` of ``u = u0 - d`` is ``-dE/du``).
    """
    u = np.asarray(u_px, dtype=np.float64)
    sig, a_, b_ = (np.asarray(x, dtype=np.float64) for x in (sigma_px, a, b))
    v = u
    small = b_ < SMALL_B
    if not small.any():
        e, e_u, e_uu = _exact(v, sig, a_, b_)
    elif small.all():
        e, e_u, e_uu = _small_b(v, sig, a_, b_)
    else:
        v, sig, a_, b_, small = np.broadcast_arrays(v, sig, a_, b_, small)
        e, e_u, e_uu = _exact(v, sig, a_, np.where(small, 1.0, b_))
        e_s, e_us, e_uus = _small_b(v[small], sig[small], a_[small], b_[small])
        e[small], e_u[small], e_uu[small] = e_s, e_us, e_uus
    if not derivatives:
        return e
    return e, e_u, sig * e_uu


def edge_response_rows(
    v: FloatArray, sig: FloatArray, a: FloatArray, b: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``edge_response(v, sig, a, b, derivatives=True)`` for rows of samples in one stacked pass (the fit's path).

    v: (N, K) distances (px); sig, a, b: (N, 1), one value per row.  The four corner points of all samples
    go through one ``ndtr`` and one ``exp`` call on a (4, N, K) array and the five signed corner sums through
    three additions: about 25 numpy calls instead of ~80 (their fixed cost dominates at a few thousand
    samples).  Rows with ``b < SMALL_B`` are evaluated at ``b0 = SMALL_B`` and taken to their own b by the
    expansion ``E(b) = E(b0) - (b0^2 - b^2) / 24 * E''(b0)`` (the same for E' and E'', whose E''' and E''''
    come from the same corner sums); this agrees with :func:`edge_response` to ~1e-9 for sigma >= 0.3 px.
    Returns E, dE/du, dE/dsigma, each (N, K).
    """
    b0 = np.maximum(b, SMALL_B)
    hp, hm = 0.5 * (a + b0), 0.5 * (a - b0)
    s = v + np.stack([hp, -hp, hm, -hm])  # (4, N, K); signs of the second difference: +, +, -, -
    inv_sig = 1.0 / sig
    terms = np.empty((5,) + s.shape)  # s^2 Phi, Phi, s phi, s Phi, phi (phi here without 1/sqrt(2 pi))
    z = s * inv_sig
    ndtr(z, out=terms[1])
    np.multiply(z, z, out=z)
    np.multiply(z, -0.5, out=z)
    np.exp(z, out=terms[4])
    np.multiply(s, terms[1], out=terms[3])
    np.multiply(s, terms[3], out=terms[0])
    np.multiply(s, terms[4], out=terms[2])
    sums = terms[:, 0] + terms[:, 1]
    sums -= terms[:, 2]
    sums -= terms[:, 3]
    s2_cdf, cdf_sum, s_pdf, s_cdf, pdf_sum = sums
    inv_ab = 1.0 / (a * b0)
    sig_c = sig * _INV_SQRT_2PI
    e = (0.5 * inv_ab) * (s2_cdf + (sig * sig) * cdf_sum + sig_c * s_pdf)
    e_u = inv_ab * (s_cdf + sig_c * pdf_sum)
    e_uu = inv_ab * cdf_sum
    small = b < SMALL_B
    if small.any():
        # ab E'' = sum(Phi), ab E''' = sum(phi) / sigma, ab E'''' = -sum(s phi) / sigma^3 (phi with 1/sqrt(2 pi))
        c = np.where(small, (b0 * b0 - b * b) / 24.0, 0.0) * inv_ab
        e -= c * cdf_sum
        e_u -= (c * _INV_SQRT_2PI * inv_sig) * pdf_sum
        e_uu += (c * _INV_SQRT_2PI * inv_sig**3) * s_pdf
    return e, e_u, sig * e_uu


def halo_edge_response(
    u_px: npt.ArrayLike,
    sigma_px: npt.ArrayLike,
    a: npt.ArrayLike,
    b: npt.ArrayLike,
    halo: tuple[float, float],
    derivatives: bool = False,
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`edge_response` for the PSF ``(1 - f) G(sigma_px) + f G(sigma_h)`` with ``halo = (f, sigma_h)``.

    Returns ``E`` or ``(E, dE/du, dE/dsigma)`` (sigma the core's width; the halo's is fixed).  At ``f = 0`` the
    values equal :func:`edge_response`'s.
    """
    fraction, halo_sigma_px = (float(v) for v in halo)
    core = edge_response(u_px, sigma_px, a, b, derivatives=derivatives)
    wide = edge_response(u_px, halo_sigma_px, a, b, derivatives=derivatives)
    if not derivatives:
        return (1.0 - fraction) * core + fraction * wide
    return ((1.0 - fraction) * core[0] + fraction * wide[0], (1.0 - fraction) * core[1] + fraction * wide[1],
            (1.0 - fraction) * core[2])


def mix_halo_rows(
    core: tuple[FloatArray, FloatArray, FloatArray], wide: tuple[FloatArray, FloatArray], fraction: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The rows of the halo mixture from the core's (E, dE/du, dE/dsigma) and the halo's (E, dE/du), each (N, K):
    ``(1 - f) core + f halo`` for E and dE/du, ``(1 - f) dE/dsigma`` (the halo's width is fixed).  Updates the
    core arrays in place and returns them."""
    e, e_u, e_s = core
    keep = 1.0 - fraction
    e *= keep
    e += fraction * wide[0]
    e_u *= keep
    e_u += fraction * wide[1]
    e_s *= keep
    return e, e_u, e_s


def edge_intensity(
    u_px: npt.ArrayLike,
    sigma_px: npt.ArrayLike,
    black_level: npt.ArrayLike,
    white_level: npt.ArrayLike,
    saturation: float,
    a: npt.ArrayLike,
    b: npt.ArrayLike,
    halo: tuple[float, float] | None = None,
) -> FloatArray:
    """Recorded intensity ``clip(Lb + (Lw - Lb) * E(u), 0, saturation)`` (same units as the levels).

    Levels may lie outside [0, saturation] (over-/underexposure); the clipping models the sensor.
    Arguments broadcast together; see :func:`edge_response`.  ``halo``: None (default, Gaussian PSF) or
    ``(fraction, sigma_px)`` of a wide halo (:func:`halo_edge_response`).
    """
    e = edge_response(u_px, sigma_px, a, b) if halo is None else halo_edge_response(u_px, sigma_px, a, b, halo)
    lb = np.asarray(black_level, dtype=np.float64)
    lw = np.asarray(white_level, dtype=np.float64)
    return np.clip(lb + (lw - lb) * e, 0.0, float(saturation))
