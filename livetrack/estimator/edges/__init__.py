"""Model-based sub-pixel edge localisation, batched over all edge points of a frame.

For each edge point (an initial position and the unit normal pointing from black to white) we take the
actual pixels of a strip along the normal (no interpolation; :mod:`livetrack.estimator.edge_samples`) and fit
the edge-formation model of
:mod:`livetrack.estimator.edge_model`, clipping included,

    I_k = clip(Lb + (Lw - Lb) * E(u_k - d; sigma, a, b), 0, S),    u_k = n . (pixel_k - point),

for the shift ``d`` along the normal, the blur ``sigma`` and the levels ``Lb``, ``Lw`` by Levenberg-Marquardt
(Nielsen's damping, internal parameters (d, sigma, visible level, log contrast)).  A model value clipped like
its data sample carries no derivative, so an over- or underexposed edge is located from its unclipped
transition samples without the bias of a threshold crossing.  Optionally the edge is a circle of given
curvature, which removes the curved-edge bias of blurred circles.

By default the iterations run compiled, one point at a time, in
:func:`livetrack.estimator.edge_kernels.levenberg_marquardt` (numba; about 2x faster per model evaluation and
without numpy's per-call overhead); ``LIVETRACK_KERNELS=numpy`` selects the numpy implementation below, the
reference the compiled kernels are tested against (they agree to ~1e-12 px).  The per-point work around the
iterations (which pixels a profile samples and their values, the start levels and crossings, the covariance and
quality flag) runs compiled too (:mod:`livetrack.estimator.edge_glue_kernels`, the same numbers except the
covariance's rounding), the clipped profiles' contrast scan stays numpy.

In the numpy reference all points are solved together: (N, K) sample arrays, (N, 4, 4) normal equations, batched 4x4
solves.  The Python loops run over iterations and over blocks of ``_BLOCK_ROWS`` points (bounded temporaries), never
over single points; a point leaves the active set once converged, i.e. once the step proposed after an accepted one
is below ``BLIND_STEP_PX`` (that step is taken without being evaluated).  Each evaluation is one stacked pass of the
model (:func:`~livetrack.estimator.edge_model.edge_response_rows`); its cost is dominated by 4 Gaussian CDFs and 4
exponentials per sample.  A clean edge takes 2-3 evaluations from the data-driven start and 1 from its own earlier
fit (``start`` of :func:`fit_edges_two_pass`).  The 5000-point test (100k samples) takes ~60 ms on one core of the
loaded development machine (~80 ms before the stacked evaluation and the proposed-step stop, measured side by side).

Heavily clipped profiles show only one tail of the edge, where blur, contrast and position are nearly
interchangeable: fit them with ``fix_sigma`` (e.g. the median sigma of the well-exposed edges of the same
frame, or a calibrated PSF width), which turns an ill-conditioned 4-parameter fit into a well-posed one,
and pass ``noise_model`` so that ``position_std_px`` reflects their (larger) uncertainty.

The package: :mod:`~livetrack.estimator.edges.solver` (model, Jacobian, Levenberg-Marquardt, :func:`fit_edges`),
:mod:`~livetrack.estimator.edges.start` (start values), :mod:`~livetrack.estimator.edges.two_pass`
(:func:`fit_edges_two_pass`); the compiled kernels are :mod:`livetrack.estimator.edge_kernels`.
"""

from livetrack.estimator.edge_model import edge_response_rows
from livetrack.estimator.edge_samples import sample_profiles
from livetrack.estimator.edges.solver import (
    BLIND_STEP_PX,
    CONVERGED_STEP_PX,
    EdgeFits,
    _evaluate,
    _evaluate_normal,
    _kernel_arrays,
    fit_edges,
)
from livetrack.estimator.edges.two_pass import fit_edges_two_pass

__all__ = [
    "BLIND_STEP_PX",
    "CONVERGED_STEP_PX",
    "EdgeFits",
    "_evaluate",
    "_evaluate_normal",
    "_kernel_arrays",
    "edge_response_rows",
    "fit_edges",
    "fit_edges_two_pass",
    "sample_profiles",
]
