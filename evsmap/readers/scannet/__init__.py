"""ScanNet v2: the ``.sens`` stream, SensReader's export, the labelled mesh and its voxelised
ground truth, the label table and the split files (the ``scannet`` reader is
:mod:`evsmap.readers.scannet.reader`)."""
