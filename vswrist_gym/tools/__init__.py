"""Command-line tools around the environments: viewer, pictures (and, elsewhere, benchmarks and probes)."""
