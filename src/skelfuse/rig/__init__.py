"""Pure rig logic between the fusion core and the daemons: which sensor frames form one instant
(grouping by device or host time) and how one instant's bodies reach the people fuser (the per-instant
adapter). No I/O, no clocks, no threads: the node, offline fusion, calibration and evaluation share it.
"""
