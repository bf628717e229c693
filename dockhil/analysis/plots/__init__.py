"""Figures and plots of runs: the paper's figures recomputed (figures.py), a run's plots (runplot.py, the
6-DOF plot6.py), the samples they read from a bag (samples.py) and how a figure file is written (figure_file.py)."""
