"""carl-sumo: Communication-Aware Reinforcement Learning for CACC platoons in Eclipse SUMO."""

__version__ = "0.1.0"
