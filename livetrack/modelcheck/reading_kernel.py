"""The mean of a clipped noisy reading (``ForwardModel.expected_reading``) in one compiled pass per frame: a
fit evaluates it at ~15 000 pixels per frame and sub-image thousands of times, where numpy's masks, gathers and
temporaries cost ~50 ns per pixel (~30 % of a model check's time on the real disks). The same formula:
``forward.expected_reading_reference`` keeps the numpy, ``tests/test_modelcheck.py`` holds one to the other
(the normal CDF is ``erfc`` here and ``scipy.special.ndtr`` there: they agree to ~1e-16)."""

from __future__ import annotations

try:  # numba is a dependency; without it (a broken install) numpy runs
    import numba
except ImportError:  # pragma: no cover - numba is installed by pyproject.toml
    numba = None

TAIL_Z = 8.5
"""A clip's term is left out where the mean is more than this many sd from it (its size < 1e-16 sd)."""

if numba is not None:
    import math

    @numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
    def expected_clipped(mean_dn, noise_a, noise_b, saturation_dn, out):  # pragma: no cover - compiled
        """``out[i] = E[clip(X, 0, S)]``, X ~ N(mean_dn[i], a + b max(mean_dn[i], 0)), for 1-D float64 arrays;
        the plain clip where the mean is more than 6 sd (at S) from both ends."""
        s = saturation_dn
        reach = 6.0 * math.sqrt(noise_a + noise_b * s)
        inv_sqrt2 = 1.0 / math.sqrt(2.0)
        inv_sqrt2pi = 1.0 / math.sqrt(2.0 * math.pi)
        for i in range(mean_dn.size):
            mu = mean_dn[i]
            m = mu
            if abs(mu - s) < reach or mu < reach:
                sd = math.sqrt(noise_a + noise_b * max(mu, 0.0))
                zt = (mu - s) / sd
                z0 = mu / sd
                # each term only where it reaches the mean's last bit (beyond TAIL_Z sd it is < 1e-16 sd)
                if zt > -TAIL_Z:  # E[X - S; X > S]
                    m -= (mu - s) * 0.5 * math.erfc(-zt * inv_sqrt2) + sd * math.exp(-0.5 * zt * zt) * inv_sqrt2pi
                if z0 < TAIL_Z:  # -E[X; X < 0]
                    m += -mu * 0.5 * math.erfc(z0 * inv_sqrt2) + sd * math.exp(-0.5 * z0 * z0) * inv_sqrt2pi
            out[i] = min(max(m, 0.0), s)
