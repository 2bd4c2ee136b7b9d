"""Model versus measurement: fit the image-formation model to an exposure series of a static black/white
pattern, compare predictions with the measurement, and choose model extensions by held-out prediction error.

Modules: ``texture`` (a disk-grid texture for the simulator), ``series`` (the input: an exposure series, from a
recording or the real ``exposure-series-disks`` folder), ``forward`` (the fast local forward model),
``fitting`` (baseline, catalogue, held-out selection), ``measure`` (bias curve, levels, residual binning),
``plots`` (PNG figures), ``simulate`` (recordings with one hidden effect), ``analysis`` (the whole pipeline).
"""
