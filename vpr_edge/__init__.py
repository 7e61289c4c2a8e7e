"""vpr-edge: visual place recognition by sequence matching of encoded deep features, on ONNX Runtime."""
__version__ = "0.1.0"
