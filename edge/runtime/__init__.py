"""Robot-side inference: ONNX Runtime only, never torch."""
