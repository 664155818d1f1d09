"""Galileo: physical object properties from video, by running Bullet inside MCMC."""
__version__ = "0.1.0"
