"""Volumetric mapping: an OctoMap-compatible occupancy octree, its file formats, and the
semantic fusion rules of the map updaters (EVSMaP Section III-B, Algorithm 1, Table IV)."""
