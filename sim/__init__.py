"""Simulated data from the model itself (known truth for tests, benchmarks and the diagnostics' experiments). Not
used by the agent in production."""
