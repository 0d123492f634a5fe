"""Network building blocks and the FEAGNet segmentation network."""
