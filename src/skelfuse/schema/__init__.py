"""The shared vocabulary: the k4abt joint set, sensor and fused frames, and the typed errors.

Everything else in skelfuse imports these; they import nothing of ours.
"""
