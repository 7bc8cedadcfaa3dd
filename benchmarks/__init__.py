"""Benchmarks and studies: scripts run from the repository root as ``python -m benchmarks.<script> [--help]``.

``_common.py`` holds what the scripts share (they never import each other); ``research/`` the research code only
the benchmarks and their tests use (matching over time, matching by likelihood ratio, mapping correction). Not an
installed package: the product packages never import it.
"""
