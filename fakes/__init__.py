"""Simulated controllers: one physics core and thin protocol front ends on loopback."""
