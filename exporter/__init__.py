"""Turns a trained run into a signed, quantized ONNX bundle (`vtkiosk export`)."""

__version__ = "0.1.0"
