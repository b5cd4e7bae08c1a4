"""Fused skeletons written to the files other tools read: BVH, FBX, C3D, OpenSim TRC, CSV.

An application layer: it reads fused frames (a fused file, or a recording fused on the way) and writes them in
the layout each format's own readers expect.
"""
