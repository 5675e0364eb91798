"""Turns a trained run into a signed, quantized ONNX bundle (`vtkiosk export`)."""

__version__ = "0.3.0"  # 0.3: graphs share one weights file (manifest schema 2). 0.2: int8 fp32 islands, native
# ConvTranspose in fp32/fp16, cheaper PE input
