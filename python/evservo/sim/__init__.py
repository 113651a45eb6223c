"""Simulation of the dual-robot servoing bench."""
