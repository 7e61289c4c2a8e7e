"""Offline tools (torch, scikit-learn): ONNX export of layer taps and codebook fitting."""
