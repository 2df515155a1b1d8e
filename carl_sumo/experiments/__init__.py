"""Experiments: simulate controllers on events, the paper's suite (tables, statistics, reports,
figures), robustness, tuning the classical CACC and benchmarks. Imports ``learn`` and below."""
