"""Segmenter plug-ins: neural networks wrapped as :class:`evsmap.interfaces.Segmenter`."""
