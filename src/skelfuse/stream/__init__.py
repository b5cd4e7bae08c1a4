"""Fused skeletons streamed live to the apps people use: OSC, the VMC protocol, Lab Streaming Layer.

An application layer: a subscriber of the fused zenoh stream that re-sends each fused frame in another protocol,
so it can run on any PC of the rig, and a receiver that is gone never blocks fusion.
"""
