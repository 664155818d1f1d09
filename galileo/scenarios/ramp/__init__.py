"""The ramp scenario of Galileo (NIPS 2015): an object slides down a ramp, maybe into a target."""
