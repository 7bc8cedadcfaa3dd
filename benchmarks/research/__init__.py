"""Research code reached only by the benchmarks and their tests, not by the product: matching over time
(temporal_matching), matching by likelihood ratio (likelihood_matching) and the mapping correction in 3-D
(mapping_correction). Moved out of ``reconstruction/`` (issue 29); import from the modules themselves."""
