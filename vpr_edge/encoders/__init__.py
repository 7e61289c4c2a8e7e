"""Encoders: a set of local descriptors (B, N, K) -> one vector per image (B, D), one contract (``base``),
one module each, one registry (``ENCODERS``). Fitting (``fit``) uses scikit-learn at build time; encoding
uses NumPy alone."""
from vpr_edge.encoders.base import Encoder, FitSettings
from vpr_edge.encoders.registry import ENCODERS, encoder_from_arrays, fit_encoder, load_codebook

__all__ = ["ENCODERS", "Encoder", "FitSettings", "encoder_from_arrays", "fit_encoder", "load_codebook"]
