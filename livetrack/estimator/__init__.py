"""Estimation from image pixels: model-based sub-pixel edges under over-/underexposure, conics, pose."""

from livetrack.estimator.edge_model import edge_intensity, edge_response, footprint_widths
from livetrack.estimator.edges import EdgeFits, fit_edges, fit_edges_two_pass

__all__ = ["EdgeFits", "edge_intensity", "edge_response", "fit_edges", "fit_edges_two_pass", "footprint_widths"]
