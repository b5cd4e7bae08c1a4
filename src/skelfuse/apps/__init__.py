"""Applications built from the whole stack: :mod:`skelfuse.apps.demo`, a simulated rig run as a real one."""
