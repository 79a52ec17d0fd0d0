"""The embedding: SubspaceNet (PyTorch), its NumPy copy for inference, the shipped weights."""
