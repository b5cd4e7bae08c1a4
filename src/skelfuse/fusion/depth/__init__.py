"""Depth-level fusion (the second source paper, Carraro, Munaro, Menegatti): person point clouds, pure stages.

Each sensor sends the points of each tracked person (its depth image masked by the body-index map). Per
person, the fusion node maps every cloud into the world (:mod:`.cloud`), optionally refines each against the
reference cloud by ICP (:mod:`.icp`), merges and voxelizes (:mod:`.cloud`), turns the merged cloud to face a
virtual camera (:mod:`.frontal`, the paper's Eqs. 3-8 plus a front/back decision from the fused skeleton),
renders a virtual depth and IR image with the paper's hole filling (:mod:`.render`, Eqs. 9-10), and maps a
skeleton found in that image back to the world (:func:`.frontal.FrontalView.to_world`); in hybrid mode that
skeleton joins skeleton fusion as one more sensor (:mod:`.hybrid`). :mod:`.pipeline` chains the stages for one
person. numpy and scipy only: the tracker call on the virtual image is an adapter (``sources/depth_tracker.py``).
"""
