"""Kinematics: sample-frame directions (θi, φi, θo, φo) <-> axis positions, for real gantry designs."""
