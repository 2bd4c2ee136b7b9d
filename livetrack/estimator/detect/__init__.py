"""Coarse detection of ring targets: concentric ellipse pairs, verified and identified by their code.

Pipeline (``detect``):

1. Map the image to 8 bits for the coarse stage with a fixed map, ``255 sqrt(v / full scale)``: no image
   statistics, so whatever else the frame holds (a saturated sky, a black night, one dark patch) a target keeps
   its levels; the square root keeps about as many levels of contrast for an underexposed target as for an
   overexposed one, and makes shot noise about level-independent.
2. A Gaussian pyramid; on each level a local threshold (mean or mid-range of a window, minus an offset from the
   local range and the camera noise; in saturated windows anything clearly below the top) marks dark pixels, and
   OpenCV's contours with two-level hierarchy give, for each dark blob, its outer boundary and its holes; on
   coarser levels also after closing 1-2 px white gaps (a small over-exposed ring cut by its grown dots). Level
   ``s`` looks for targets whose outer semi-minor axis is 8..48 pixels *of that level* (the full-resolution
   level: ``min_outer_radius_px``..24), so the window always spans the black ring, whatever the target's size.
   The full-resolution level is slightly blurred first (texture), and the local statistics come from two levels
   down (cheap).
3. Cheap tests (size, a hole near the middle with about (r/R)^2 of the blob's area, solidity), then ellipses
   fitted to the outer boundary and to the holes (filtered by fit residual, area and aspect); a pair is kept
   when the hole is concentric with the blob and both semi-axis ratios match some configured r/R (with room for
   an exposure bias of a few pixels on each edge). A tiny ring (outer semi-minor axis up to 16 px) that the
   threshold joined to dark ground is also placed from its inner disk (a hole, or a closing's) on the grey
   image's edges (``refine.pair_from_disk``), and read with the strict rules of pairs from a hole alone.
4. Each pair is refined on a crop of the finest pyramid level on which the target is at most
   ``refine_max_radius_px`` big, with a global threshold halfway between its own black and white levels.
5. Verification and identification on the original image: the homography implied by the two concentric ellipses
   (up to the in-plane rotation) maps target-plane sample points to the image; the black annulus must be dark
   (between the inner disk and the code dots, between the dots and the outer edge, and in every gap between two
   slots; where the pair's seen ring thickness puts them: over-exposure thins the bands and grows the dots), the
   inner disk bright, with a contrast relative to the target's own white. The slot grid's phase comes from
   the N-th circular harmonic of the code circle;
   each slot's value is normalised between the black and white levels and decoded against the configured codes
   (only those of the geometry that matched). No code match: no candidate.
6. Fractal levels: a nested target is found as its own pair; when its code does not tell the level (the default
   design repeats the code), a detected parent around it decides, else the parent's own code read around it
   (in the same frame, on whatever part of the parent's code circle is in the image).

Limits: the code needs an outer radius of about 9 px or more (8 px blurred targets fail); at 4x overexposure
the white dots swell into the inner disk for outer radii below ~25 px, and such targets are missed.

Cost: mostly the full-resolution passes of steps 1-2 (16-to-8-bit conversion, blur, first pyramid step, the
upsampled local threshold and its comparison) and the ellipse fits. The full-size work images (8-bit image,
pyramid, blurred level 0, threshold image: about 3.5 bytes per pixel of the largest image seen) are kept by the
``Detector`` from one call to the next and overwritten: a fresh multi-megabyte array costs its page faults, more
than a pass over it. Contours are traced over the bounding box of a level's dark pixels only; the homography of
step 5 is computed in scalar arithmetic.

Modules: ``detector`` (the entry point), ``threshold`` (8-bit map, noise, local threshold), ``pairs``
(ellipse pairs of a binary image) with ``fits`` (contour ellipse fits), ``hole_pairs`` (pairs from a blob's holes
alone), ``small_blobs`` (small blobs without a pair), ``arc_pairs`` (pairs of a ring's arcs) and ``places``
(de-duplication by place), ``refine``, ``code`` (verification and code), ``levels`` (fractal levels), ``results``
and ``options``.

Pixel convention: (x, y), (0, 0) the centre of the top-left pixel; ``image[y, x]``.
"""

from livetrack.estimator.detect.detector import Detector, detect
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.results import Candidate, TraceEvent
from livetrack.estimator.detect.threshold import full_scale

__all__ = ["Candidate", "DetectOptions", "Detector", "TraceEvent", "detect", "full_scale"]
