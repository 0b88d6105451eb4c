"""The builder's scene in reduced coordinates, in MuJoCo (`mujoco`) and pinocchio (`pinocchio`).

`reduced` turns the builder's joints into a tree of elementary joints that both peers share. Every module
imports its engine only when called, so the harness imports without the `bench` extra.
"""
