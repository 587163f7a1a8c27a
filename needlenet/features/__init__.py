"""Feature sources: classical features from the papers and learned ONNX likelihood maps."""
