"""Identification: surface mesh, membrane kinematics, constitutive models and the Virtual Fields Method.

Pure functions over arrays: no files, ports or clocks.
"""
