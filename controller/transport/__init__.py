"""Transports between the loop and a valve: the in-process simulated valve and Zenoh."""
