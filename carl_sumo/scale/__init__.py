"""Running work in parallel: spawned worker processes (one libsumo each) and the Ray cluster.
Imports nothing of the package but ``errors``."""
