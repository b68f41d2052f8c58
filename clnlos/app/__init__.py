"""The command line and the fronts it calls: simulate, reconstruct, demo, progress bars."""
