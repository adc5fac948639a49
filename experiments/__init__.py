"""Experiments users run: one closed-loop slew, Monte Carlo campaigns, the agent benchmark, and the CLI."""
