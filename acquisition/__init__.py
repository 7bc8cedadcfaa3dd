"""Acquisition: instruments, cameras, the session file and the operator's session runner.

This is the only stage that talks to hardware; it writes the HDF5 session file that the
other stages read (see ``docs/session-format.md``).
"""
