"""Online skeleton regression from depth: person finding, the ONNX model, temporal filtering."""
