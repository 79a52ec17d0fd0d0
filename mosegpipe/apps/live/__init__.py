"""Live mode (`moseg live`): sources, the reader thread, the run."""
